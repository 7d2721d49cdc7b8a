"""Fit the Spencer et al. (1997) MR-damper model to sinusoid tests of a real damper.

Data: the sinusoid tests of an MR damper at 0, 0.25, 0.5, 0.75 and 1 A in
GitHub DanielMaurelE/vRTHS_AMBC_MRdamper (MIT licence, (c) 2022 mequiroz),
``Cap7_ModeloMR/BoucWen Ajuste 1/Preprocesamiento-sinusoidales/Preprocesados/*.txt``:
columns t [s], x [mm], v [mm/s], F [N]; file names ``<amp>mm<freq>Hz<current>A.txt``
with ``x`` for the decimal point (``25mm0x5Hz0x75A``: 25 mm, 0.5 Hz, 0.75 A).
The files are not redistributed: :func:`load_tests` reads them from a directory
the user gives (``rths fit-mr --data DIR``), else from the data set's folder
``mr_damper/`` of :func:`rths_common.datasets.data_dir` (``$RTHS_DATA_DIR``, by default
``../shared/data`` beside the repository).

The model is that of :mod:`.mr_damper` with the current ``i`` [A] in place of the
voltage (``alpha = alpha_a + alpha_b i``, same for c0 and c1; n = 2 as in the
paper; ``x0`` and ``eta`` drop out of a tared force at constant current).  Each
test is simulated over 1.25 cycles from its first sample (``y = x``, ``z = 0``)
with the measured stroke and velocity as inputs, on 1000 points per cycle with
a linearly implicit step in ``z`` (stable for the stiff Bouc-Wen term; within
1 % of RK4 on 8000 points per cycle); the last cycle is scored.  All tests are
fitted at once (one parameter set for every current) by least squares on the
force normalised by each test's RMS force, parameters in log scale.
"""

import glob
import os
import re

import numpy as np
from scipy.optimize import least_squares

from rths_common import datasets

from .mr_damper import SPENCER_1997, MRParameters

#: Fitted parameters (all but n, x0, eta), in this order.
FIT_KEYS = ('c0a', 'c0b', 'k0', 'c1a', 'c1b', 'k1', 'alpha_a', 'alpha_b', 'gamma', 'beta', 'A')
SOURCE = {
    'repository': 'https://github.com/DanielMaurelE/vRTHS_AMBC_MRdamper',
    'path': 'Cap7_ModeloMR/BoucWen Ajuste 1/Preprocesamiento-sinusoidales/Preprocesados/*.txt',
    'licence': 'MIT, Copyright (c) 2022 mequiroz',
    'columns': 't [s], x [mm], v [mm/s], F [N]',
}
_NAME = re.compile(r'(\d+(?:x\d+)?)mm(\d+(?:x\d+)?)Hz(\d+(?:x\d+)?)A\.txt$')


def data_dir(path=None):
    """Return ``path``, else the data set's folder (:mod:`rths_common.datasets`: mr_damper).

    OSError naming the data set, its source and the fix (``--data DIR``) when neither is there.
    """
    if path:
        return path
    try:
        return str(datasets.dataset_dir('mr_damper'))
    except OSError as err:
        raise OSError(f'no MR-damper data: give --data DIR, or {err}') from None


def load_tests(directory):
    """Read every ``<amp>mm<freq>Hz<current>A.txt`` test of ``directory`` (SI units)."""
    tests = []
    for path in sorted(glob.glob(os.path.join(directory, '*.txt'))):
        m = _NAME.match(os.path.basename(path))
        if not m:
            continue
        amp, freq, current = (float(g.replace('x', '.')) for g in m.groups())
        data = np.loadtxt(path)
        if data.ndim != 2 or data.shape[1] != 4:
            raise ValueError(f'{path}: expected 4 columns t [s], x [mm], v [mm/s], F [N]')
        t, x, v, f = data.T
        tests.append({'name': os.path.basename(path)[:-4], 'amp_m': amp / 1e3, 'freq_hz': freq,
                      'current_a': current, 't': t, 'x': x / 1e3, 'v': v / 1e3, 'force': f})
    if not tests:
        raise OSError(f'{directory}: no test files named like 10mm1Hz0x5A.txt '
                      f"(the Preprocesados folder of {SOURCE['repository']})")
    return tests


def _inputs(tests, per_cycle, cycles):
    """Stroke, velocity and measured force resampled on ``per_cycle`` points per cycle."""
    n = int(round(per_cycle * cycles))
    shape = (n + 1, len(tests))
    x, v, f, h = np.zeros(shape), np.zeros(shape), np.zeros(shape), np.zeros(len(tests))
    for i, test in enumerate(tests):
        span = cycles / test['freq_hz']
        if test['t'][-1] - test['t'][0] < span:
            raise ValueError(f"test {test['name']} is shorter than {cycles} cycles")
        ts = test['t'][0] + np.linspace(0.0, span, n + 1)
        h[i] = span / n
        x[:, i] = np.interp(ts, test['t'], test['x'])
        v[:, i] = np.interp(ts, test['t'], test['v'])
        f[:, i] = np.interp(ts, test['t'], test['force'])
    return x, v, f, h


def simulate_tests(params: MRParameters, tests, per_cycle=1000, cycles=1.25, inputs=None,
                   level=None):
    """Model force [N] of every test (columns) on the resampled grid; also the measured force.

    ``level`` [per test] replaces the current as the model's ``u`` (e.g. a
    voltage for the paper's parameters); default the tests' currents.
    """
    x, v, f, h = inputs if inputs is not None else _inputs(tests, per_cycle, cycles)
    u = np.array([t['current_a'] for t in tests]) if level is None else np.asarray(level)
    p = params
    alpha, c0, c1 = p.alpha_a + p.alpha_b * u, p.c0a + p.c0b * u, p.c1a + p.c1b * u
    cs = c0 + c1
    z = np.zeros(len(tests))
    y = x[0].copy()
    force = np.zeros_like(x)
    force[0] = c1 * (c0 * v[0]) / cs + p.k1 * x[0]
    stiff = p.A * alpha / cs
    for k in range(x.shape[0] - 1):
        x1, v1 = x[k + 1], v[k + 1]
        q = c0 * v1 + p.k0 * (x1 - y)
        r = v1 - (alpha * z + q) / cs
        d = p.gamma * np.abs(r) * np.abs(z) + p.beta * r * z
        dp = np.maximum(d, 0.0)
        z = (z + h * (p.A * v1 - p.A * q / cs - (d - dp) * z)) / (1.0 + h * (stiff + dp))
        y = y + h * (alpha * z + q) / cs
        force[k + 1] = c1 * (alpha * z + c0 * v1 + p.k0 * (x1 - y)) / cs + p.k1 * x1
    return force, f


def _scored(arr, per_cycle):
    return arr[-per_cycle:]


def errors_pct(model, measured, per_cycle):
    """Relative RMS error [%] of each test over its scored (last) cycle."""
    m, d = _scored(model, per_cycle), _scored(measured, per_cycle)
    return 100 * np.sqrt(np.mean((m - d) ** 2, axis=0) / np.mean(d ** 2, axis=0))


def _params(theta, base=SPENCER_1997):
    values = base.as_dict()
    values.update(dict(zip(FIT_KEYS, np.exp(theta), strict=True)))
    return MRParameters(**values)


def fit(tests, start: MRParameters = None, per_cycle=1000, max_nfev=200, progress=None):
    """Least-squares fit of :data:`FIT_KEYS` to all tests; return (parameters, errors [%]).

    ``progress(done, 0)`` gets the number of model evaluations so far (total unknown).
    """
    if start is None:   # the paper's values, its voltage dependence spread over 0-1 A
        start = _params(np.log([getattr(SPENCER_1997, k) * (2.25 if k.endswith('b') else 1.0)
                                for k in FIT_KEYS]))
    inputs = _inputs(tests, per_cycle, 1.25)
    scale = np.sqrt(np.mean(_scored(inputs[2], per_cycle) ** 2, axis=0))

    calls = [0]

    def residual(theta):
        calls[0] += 1
        if progress is not None:
            progress(calls[0], 0)
        model, measured = simulate_tests(_params(theta), tests, inputs=inputs)
        res = (_scored(model, per_cycle) - _scored(measured, per_cycle)) / scale
        return np.nan_to_num(res.ravel(), nan=1e3, posinf=1e3, neginf=-1e3)

    theta0 = np.log([getattr(start, k) for k in FIT_KEYS])
    sol = least_squares(residual, theta0, method='trf', x_scale=1.0, diff_step=1e-3,
                        max_nfev=max_nfev)
    best = _params(sol.x)
    model, measured = simulate_tests(best, tests, inputs=inputs)
    return best, errors_pct(model, measured, per_cycle), int(sol.nfev)


def comparable(params: MRParameters, level=1.0):
    """Quantities that do not depend on the Bouc-Wen scaling of ``z`` (to compare fits).

    ``z_max = (A / (gamma + beta))^(1/n)``; the hysteretic force ``alpha z_max``
    at level 0 and ``level`` (1 A or 2.25 V); the high-velocity viscous slope
    ``c0 c1 / (c0 + c1)`` at both.
    """
    p = params
    z_max = (p.A / (p.gamma + p.beta)) ** (1.0 / p.n)
    out = {'z_max_m': z_max}
    for label, u in (('0', 0.0), ('max', float(level))):
        alpha, c0, c1 = p.at(u)
        out[f'hysteretic_force_n_at_{label}'] = alpha * z_max
        out[f'viscous_slope_n_s_m_at_{label}'] = c0 * c1 / (c0 + c1)
    out['level_max'] = float(level)
    return out


def paper_errors(tests, per_cycle=1000, voltages=None):
    """Score the paper's parameters on these tests at the best voltage per current.

    Per current: the best constant voltage [V] of ``voltages`` (default 0-2.25 V
    in 0.05 V steps) and the relative RMS errors [%] there (the paper's damper
    is another device).
    """
    voltages = np.linspace(0.0, 2.25, 46) if voltages is None else voltages
    inputs = _inputs(tests, per_cycle, 1.25)
    currents = np.array([t['current_a'] for t in tests])
    out = {}
    for cur in sorted(set(currents)):
        idx = np.flatnonzero(currents == cur)
        sub = [tests[i] for i in idx]
        sub_in = tuple(a[:, idx] for a in inputs[:3]) + (inputs[3][idx],)
        best = None
        for volt in voltages:
            model, meas = simulate_tests(SPENCER_1997, sub, inputs=sub_in,
                                         level=np.full(len(sub), volt))
            err = errors_pct(model, meas, per_cycle)
            if best is None or err.mean() < best[1].mean():
                best = (float(volt), err)
        out[f'{cur:g}'] = {'best_voltage_v': best[0],
                           'errors_pct': dict(zip([t['name'] for t in sub],
                                                  best[1].tolist(), strict=True))}
    return out
