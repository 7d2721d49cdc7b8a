"""Nominal models of the two scenarios, their YAML layouts and their simulators.

Specimen: the DTM damper on the shake table (seed eq. 46-47, Table 4)::

    m_d xdd_d2s + c_d xd_d2s + k_d x_d2s = -m_d xdd_s                       (46)
    T_DTM(s) = X_d2s / Xdd_s = -m_d / (m_d s^2 + c_d s + k_d)                (47)

The force the damper exerts on its frame is ``c_d xd + k_d x = -m_d xdd_d``
(eq. 45).  The linear part is discretised with a first-order hold (the input
acceleration is linear between samples); the full non-linear model is
integrated with classical Runge-Kutta (RK4) on the same linear interpolation.

Actuator: a continuous model ``T(s)`` (default: Table 1 3-pole, unit DC
gain, seed eq. 3) or an identified ARX model (seed eq. 26).  Timing
convention: the command ``u_k`` is held for one sample (ZOH) and the
measurement labelled ``k`` is read at the end of that sample, i.e. the ZOH
discretisation with its one sample of pure delay dropped (d = 0).

YAML layouts (all SI)::

    {kind: dtm, m_d: 258.35, c_d: 491.6, k_d: 80810.0, effects: {NAME: VALUE, ...}}
    {kind: continuous, table1: 3pole, effects: {...}}
    {kind: continuous, poles: [[re, im], ...], dc_gain: 1.0, effects: {...}}
    {kind: continuous, num: [...], den: [...], effects: {...}}       # in s
    {kind: arx, fs_hz: 1024, na: 2, nb: 2, d: 0, a: [1, a1, a2], b: [b1, b2], effects: {...}}

``effects`` (optional) maps the names of :mod:`rths_discrepancy.effects` to
their parameter value; the workflow writes ``updated_model.yaml`` in the
same layout, so it loads back with ``--model``.
"""

import copy
from dataclasses import dataclass, field
import math

import numpy as np
from scipy import signal

from rths_common import yamlfile
from rths_common.timebase import same_rate
from rths_compensator.plants import continuous_actuator
from rths_discrepancy import effects as fx
from rths_numerical.dtm import SEED_CONFIGURATION, dtm_configuration


@dataclass
class SpecimenModel:
    """DTM damper model (eq. 46) plus added effects ``{name: value}``."""

    m_d: float
    c_d: float
    k_d: float
    effects: dict = field(default_factory=dict)

    scenario = 'specimen'

    def linear_filter(self, fs: float):
        """Discrete (b, a) of eq. 47 (input: acceleration, output: x_d2s), FOH at ``fs``."""
        num, den, _ = signal.cont2discrete(([-self.m_d], [self.m_d, self.c_d, self.k_d]),
                                           1.0 / fs, method='foh')
        return np.ravel(num), np.ravel(den)

    def to_dict(self) -> dict:
        """YAML-ready dictionary."""
        out = {'kind': 'dtm', 'm_d': float(self.m_d), 'c_d': float(self.c_d),
               'k_d': float(self.k_d)}
        if self.effects:
            out['effects'] = {k: float(v) for k, v in self.effects.items()}
        return out

    def simulate(self, base_accel, fs: float, substeps: int = 1):
        """Simulate the full model; return dict with 'rel_disp' and 'force' (measured-like).

        RK4 on ``m xdd + c xd + k x + f(x, xd) = -(m + dm)(xdd_s) - dm xdd`` with
        the input linearly interpolated; ``force = -(m_d + dm) xdd_d``.  Output
        operators (time_delay, sensor_bias) are applied afterwards.
        """
        eff = self.effects
        m = self.m_d + eff.get('mass_error', 0.0)
        c, k = self.c_d, self.k_d
        f_nl = fx.specimen_force(eff, self)
        u = np.asarray(base_accel, dtype=float)
        h = 1.0 / (fs * substeps)
        n = u.size
        xs = np.empty(n)
        fs_out = np.empty(n)
        x = v = 0.0
        ul = u.tolist()

        def acc(x, v, us):
            return -us - (c * v + k * x + f_nl(x, v)) / m

        xs[0] = 0.0
        fs_out[0] = 0.0
        for i in range(n - 1):
            u0, u1 = ul[i], ul[i + 1]
            du = (u1 - u0) / substeps
            for j in range(substeps):
                ua = u0 + j * du
                um = ua + 0.5 * du
                ub = ua + du
                k1x, k1v = v, acc(x, v, ua)
                k2x, k2v = v + 0.5 * h * k1v, acc(x + 0.5 * h * k1x, v + 0.5 * h * k1v, um)
                k3x, k3v = v + 0.5 * h * k2v, acc(x + 0.5 * h * k2x, v + 0.5 * h * k2v, um)
                k4x, k4v = v + h * k3v, acc(x + h * k3x, v + h * k3v, ub)
                x += h / 6.0 * (k1x + 2 * k2x + 2 * k3x + k4x)
                v += h / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v)
            xs[i + 1] = x
            fs_out[i + 1] = c * v + k * x + f_nl(x, v)
        out = {'rel_disp': fx.apply_output_ops('specimen', xs, eff, fs, 'x'),
               'force': fx.apply_output_ops('specimen', fs_out, eff, fs, 'force')}
        return out


@dataclass
class ActuatorModel:
    """Actuator model: continuous (num, den in s) or ARX (b, a at fs_hz, delay d)."""

    kind: str
    num: np.ndarray = None
    den: np.ndarray = None
    fs_hz: float = None
    a: np.ndarray = None
    b: np.ndarray = None
    d: int = 0
    source: dict = None
    effects: dict = field(default_factory=dict)

    scenario = 'actuator'

    def linear_filter(self, fs: float):
        """Discrete (b, a) from command to measurement under the timing convention."""
        if self.kind == 'arx':
            if not same_rate(self.fs_hz, fs):
                raise ValueError(f'ARX model is for fs_hz={self.fs_hz} but the data are sampled '
                                 f'at {fs:g} Hz; identify the model at the data rate')
            return np.concatenate([np.zeros(self.d), self.b]), np.asarray(self.a, float)
        num, den, _ = signal.cont2discrete((self.num, self.den), 1.0 / fs, method='zoh')
        num = np.ravel(num)
        if abs(num[0]) > 1e-12 * np.max(np.abs(num)):
            raise ValueError('continuous actuator model must be strictly proper')
        return num[1:], np.ravel(den)

    def to_dict(self) -> dict:
        """YAML-ready dictionary (same layout as it was loaded from)."""
        src = {k: (v.tolist() if isinstance(v, np.ndarray) else v)
               for k, v in (self.source or {}).items()}
        out = src if src else {
            'kind': 'continuous', 'num': [float(v) for v in self.num],
            'den': [float(v) for v in self.den]}
        out.pop('effects', None)
        if self.effects:
            out['effects'] = {k: float(v) for k, v in self.effects.items()}
        return out

    def simulate(self, command, fs: float, substeps: int = 1):
        """Simulate the full model; return dict with 'measured'.

        The loop load ``q`` (friction, stiffness, damping, inertia loads) is
        evaluated at the middle of each (sub)step (centred differences of the
        output, :func:`_loop_filter`) and held with the command over it; output
        operators are applied after.
        """
        u = np.asarray(command, dtype=float)
        load = fx.actuator_load(self.effects)
        has_loop = any(k in self.effects for k in (
            'coulomb_friction', 'viscous_damping_error', 'stiffness_error',
            'cubic_stiffness', 'mass_error', '_stribeck'))
        if self.kind == 'arx':
            substeps = 1
        fsub = fs * substeps
        bq, aq = self.linear_filter(fsub) if self.kind != 'arx' else self.linear_filter(fs)
        if not has_loop:
            y = signal.lfilter(bq, aq, np.repeat(u, substeps))
        else:
            y = _loop_filter(bq, aq, np.repeat(u, substeps), load, fsub)
        y = y[substeps - 1::substeps]
        return {'measured': fx.apply_output_ops('actuator', y, self.effects, fs)}


def _loop_filter(b, a, u, load, fs):
    """Difference equation ``a(z) y = b(z) (u - q)`` with ``q = load(y, v, acc)``.

    ``q_k``, held with ``u_k`` over sample k (from ``t_{k-1}`` to ``t_k``), is the load at
    the middle of that sample, where a load that varies over the sample (the lab's, from
    the continuous state) has its mean: displacement ``(y_k + y_{k-1}) / 2`` and velocity
    ``(y_k - y_{k-1}) fs`` (centred differences), acceleration extrapolated from the last
    two second differences (``1.5 a_{k-1} - 0.5 a_{k-2}``).  ``y_k`` depends on ``q_k``
    through ``b_0``: the scalar equation is solved by Newton's method (a secant slope; one
    step for a linear load, explicit when ``b_0 = 0``).  (A backward difference,
    ``q_k`` from ``y_{k-1}, y_{k-2}``, read the velocity 1.5 samples late: a hidden
    Coulomb load was fitted 16-25 % small, with a play absorbing the rest.)
    """
    a0 = float(a[0])
    b = [float(v) / a0 for v in b]
    a = [float(v) / a0 for v in a]
    nb, na = len(b), len(a)
    b0 = b[0]
    n = u.size
    ul = u.tolist()
    ys = [0.0] * n
    ws = [0.0] * n
    y1 = y2 = y3 = 0.0
    fs2 = fs * fs

    def q_at(y):
        acc = (1.5 * (y - 2.0 * y1 + y2) - 0.5 * (y1 - 2.0 * y2 + y3)) * fs2
        return load(0.5 * (y + y1), (y - y1) * fs, acc)

    for k in range(n):
        s = 0.0
        for j in range(1, nb):
            if k - j >= 0:
                s += b[j] * ws[k - j]
        for i in range(1, na):
            if k - i >= 0:
                s -= a[i] * ys[k - i]
        uk = ul[k]
        y = s + b0 * (uk - q_at(y1))
        if b0 != 0.0:
            for _ in range(30):   # g(y) = y - s - b0 (u_k - q(y)) = 0
                qy = q_at(y)
                g = y - s - b0 * (uk - qy)
                h = 1e-7 * max(abs(y), 1e-6)
                slope = 1.0 + b0 * (q_at(y + h) - qy) / h
                step = g / slope if slope != 0.0 else g
                y -= step
                if abs(step) <= 1e-14 * max(abs(y), 1e-12):
                    break
        q = q_at(y)
        ws[k] = uk - q
        y = s + b0 * ws[k]
        ys[k] = y
        y3, y2, y1 = y2, y1, y
    return np.array(ys)


def default_model(scenario: str):
    """Nominal model of a scenario without ``--model``: Table 4 valve #4 or Table 1 3-pole."""
    if scenario == 'specimen':
        p = dtm_configuration(SEED_CONFIGURATION)
        return SpecimenModel(p.m_d, p.c_d, p.k_d)
    if scenario == 'actuator':
        return actuator_from_dict({'kind': 'continuous', 'table1': '3pole'})
    raise ValueError(f'unknown scenario {scenario!r}; use specimen or actuator')


def _effects_from(spec: dict, where: str) -> dict:
    eff = spec.get('effects') or {}
    if not isinstance(eff, dict):
        raise ValueError(f'{where}: effects must be a mapping NAME: VALUE')
    for name in eff:
        if name not in fx.EFFECT_NAMES:
            raise ValueError(f'{where}: unknown effect {name!r}; use one of '
                             f'{", ".join(fx.EFFECT_NAMES)}')
    return {k: float(v) for k, v in eff.items()}


def actuator_from_dict(spec: dict, where: str = 'model') -> ActuatorModel:
    """Build an :class:`ActuatorModel` from a YAML dictionary (layouts in the module doc)."""
    kind = spec.get('kind')
    eff = _effects_from(spec, where)
    if kind == 'arx':
        for key in ('fs_hz', 'a', 'b'):
            if key not in spec:
                raise ValueError(f'{where}: ARX model needs {key!r}')
        a = np.asarray(spec['a'], float)
        if a[0] != 1.0:
            raise ValueError(f'{where}: ARX a must start with 1 (a: [1, a1, ...])')
        return ActuatorModel('arx', fs_hz=float(spec['fs_hz']), a=a,
                             b=np.asarray(spec['b'], float), d=int(spec.get('d', 0)),
                             source=dict(spec), effects=eff)
    if kind == 'continuous':
        if 'table1' in spec:
            num, den = continuous_actuator(str(spec['table1']))
        elif 'poles' in spec:
            poles = np.array([complex(p[0], p[1]) if isinstance(p, (list, tuple)) else
                              complex(p) for p in spec['poles']])
            den = np.real(np.poly(poles))
            num = np.array([float(spec.get('dc_gain', 1.0)) * float(np.real(np.prod(-poles)))])
        elif 'num' in spec and 'den' in spec:
            num, den = np.asarray(spec['num'], float), np.asarray(spec['den'], float)
        else:
            raise ValueError(f'{where}: continuous model needs table1, poles or num/den')
        return ActuatorModel('continuous', num=np.asarray(num, float),
                             den=np.asarray(den, float), source=dict(spec), effects=eff)
    raise ValueError(f'{where}: actuator model kind must be continuous or arx, not {kind!r}')


def model_from_dict(scenario: str, spec: dict, where: str = 'model'):
    """Build the model of ``scenario`` from a YAML dictionary."""
    if not isinstance(spec, dict):
        raise ValueError(f'{where}: expected a YAML mapping with a kind field')
    if scenario == 'specimen':
        if spec.get('kind') != 'dtm':
            raise ValueError(f'{where}: specimen model needs kind: dtm')
        try:
            m, c, k = (float(spec[key]) for key in ('m_d', 'c_d', 'k_d'))
        except KeyError as err:
            raise ValueError(f'{where}: dtm model needs {err.args[0]!r}') from None
        if not (m > 0 and k > 0 and c >= 0 and math.isfinite(m + c + k)):
            raise ValueError(f'{where}: need m_d > 0, k_d > 0, c_d >= 0')
        return SpecimenModel(m, c, k, _effects_from(spec, where))
    return actuator_from_dict(spec, where)


def load_model(scenario: str, path):
    """Load a model YAML file (ValueError names the file and the problem)."""
    return model_from_dict(scenario, yamlfile.load(path), where=str(path))


def with_effects(model, effects: dict):
    """Copy of ``model`` with ``effects`` added to (overriding) its own."""
    new = copy.copy(model)
    new.effects = {**model.effects, **effects}
    return new
