"""Restoring-force scenario: what a linear ``m a + c v + k x`` misses in a measured specimen force.

Input (CSV with a header row; other columns are ignored; any uniform rate, any
units as long as they are consistent -- a record in volts works, the workflow
assumes no magnitudes): ``time_s``, ``displacement_m``, ``force_N`` and
optionally ``velocity_m_s``.

States.  Scale-free and fitted to the record's band (``f99`` the frequency below
which 99 % of a signal's power lies): the upper cut-off ``fc_max = 4 f99(force)``
within [10 f99(displacement), ``FC_MAX`` fs]; the cut-off ``fc`` is chosen by the
data on ``FC_GRID`` values from the displacement's 99.9 % band edge up to
``fc_max``: the highest whose linear fit of the force (``a, v, x, 1``, the whole
record but its edges) leaves within ``FC_TIE`` of the least residual.  Noise
differentiated twice past the motion's band enters the regressors and raises the
residual (a broadband record at 3300 Hz with 0.4 % displacement noise: 72 % NRMSE
at ``fc_max``, 3 % at the chosen one); a noise-free record keeps ``fc_max``.
That linear fit does not see what the candidates add: on a friction record its
residual is the friction, flat over a wide range of cut-offs, and the highest of
them leaves velocity noise that flips the friction's sign at every reversal.  So
the candidates choose in the end (:func:`candidates_cutoff`): the ``CUTOFF_TOP``
best candidates, their shapes and alignments kept, are solved again on the states
at every cut-off of the grid, and the highest cut-off within ``FC_TIE`` of their
least held-out error is taken; where it is not the linear fit's, every candidate
is fitted again on its states.  Both errors per cut-off are in result.json.
The differentiator
(:data:`DIFFERENTIATORS`, reported in result.json):

* ``spectral, whole periods`` -- displacement and force repeat (a periodic
  multisine, a sine test; :func:`signals.period` to within ``PERIOD_TOL`` of their
  spread): the record is cut to its whole periods and differentiated in the
  frequency domain, tapered from ``fc`` to ``1.25 fc``;
* ``spectral, smoothing`` -- any other record whose band reaches past
  ``CENTRAL_MAX`` fs (a broadband excitation, where central differences lose gain:
  24 % at fs / 5): the stated smoothing differentiator of :mod:`.signals` (end
  line removed, raised-cosine low-pass from ``fc`` to ``1.25 fc``);
* ``butterworth, central differences`` -- slow records (band below
  ``CENTRAL_MAX`` fs, the loss under 1.6 %): a zero-phase 4th-order Butterworth
  low-pass at ``fc``, central differences, low-passed again.

Velocity from the displacement unless given (a given velocity is smoothed alike).
The measured force is *not* filtered: every NRMSE is on the force as recorded.

Models, all linear in their amplitudes (least squares) with at most one shape
parameter each (a grid and a bounded search, relative to the data's own scales)::

    nominal                m a + c v + k x
    coulomb_friction       + F_c tanh(v / v_eps)                     (v_eps searched)
    asymmetric_friction    + F_p tanh+(v / v_eps) + F_n tanh-(v / v_eps)
    stribeck               + (F_c + (F_s - F_c) exp(-(v / v_s)^2)) tanh(v / v_eps)
    force_offset           + F_0 (offset of the load-cell reading: as in the specimen
                             scenario, rths_discrepancy.effects)
    cubic_stiffness        + k3 x^3
    quadratic_damping      + c2 v |v|   (a fluid damper, drag: the velocity-squared law)
    backlash               + k_b dz(x, b) + F_b e(x, z, v) tanh(v / v_eps), a clearance
                             (play) of half-width b: a spring engaging beyond it,
                             friction through it (z = play(x, b), its far side: no
                             force while the clearance is crossed after each reversal;
                             e = 1 where the sample is at the clearance's edge pushing
                             the far side, x - z = b sign(v), else 0); v_eps chosen by
                             the data (training error of the backlash candidate, with
                             the force's constant, over BACKLASH_EPS x rms(v))
    hysteresis             + alpha z, Bouc-Wen with beta = gamma = 1/2, n = 1:
                             dz = dx / x_y (1 - |z| (1 + sign(dx z)) / 2)   (x_y searched)
    time_delay             the model's force lags its states by tau (|tau| beyond
                           the alignment band: inside it, a lag is an alignment)

with ``tanh+ = max(tanh, 0)``, ``tanh- = min(tanh, 0)``, ``v_eps`` searched in
[1e-4, 0.03] x rms(v) (a regularised Coulomb law must saturate within the
velocity range; a wider ``tanh`` would be a second viscous term).  The
model-measurement alignment (within +-1.5 samples) is a nuisance parameter of
every fit (Gauss-Newton on the shifted states, from the nominal's alignment, and
from none as well where the nominal's leans ``ALIGN_LEAN`` of a sample or more:
:func:`alignment_starts`).  The specimen scenario's
viscous_damping_error, stiffness_error and mass_error have no place here:
``m``, ``c`` and ``k`` are fitted with every candidate.

Decision (held out: the later part of the record, the first ``TRAIN_FRACTION``
trains).  Scores are held-out mean square force errors; every single effect
and every pair is fitted; the winner minimises the held-out information
criterion ``N ln(mse) + p ln N`` among the candidates that beat the nominal;
a pair replaces the best single only if its criterion is lower and, when it
has more parameters, it also removes ``PAIR_CUT`` of the single's error above
the white-noise floor and ``PAIR_REL_GAIN`` of the nominal model's (a pair with
as many parameters as the single, e.g. Coulomb friction + offset against
asymmetric friction, needs only the lower criterion).  The Stribeck law, which
holds Coulomb friction, is named in its place by the same rule: it must remove
``PAIR_CUT`` of the error the Coulomb law leaves above the floor (its bump about
zero velocity otherwise bends the smeared reversals of a Coulomb record).  Below ``MIN_REL_GAIN``
of the nominal's error the answer is ``none``; if the winner leaves more than
``UNEXPLAINED_LEFT`` of the nominal's error above the white-noise floor (read in
the residual's spectrum above the states' band), ``unexplained``.

Drift (a nuisance, never an effect: :func:`decide_drift`).  A load cell's zero
moves over a test; a line ``F_d (t - t_0) / T`` from the record's first sample is
a term of every model when, on the candidate of the lowest criterion, it lowers
the held-out criterion (fitted on the training part, carried over the held-out
part); the candidates are then fitted again with it.  Without it a drifting
linear record was named ``force_offset`` (the line's mean) or ``unexplained``.

Equivalent decompositions (:data:`EQUIVALENT`).  Asymmetric friction is
``F_c tanh(v / v_eps) + F_0 |tanh(v / v_eps)|`` with ``F_c = (F_p + F_n) / 2``
and ``F_0 = (F_p - F_n) / 2``: while the specimen slides (``|v| >> v_eps``) it
*is* Coulomb friction plus a constant force, the same two force levels.  The
two readings differ only where the velocity rests, in the stick band where a
regularised friction law is not the physics either.  So a winner holding
``asymmetric_friction`` is named only if it beats its decomposition into the
library's elementary effects (``coulomb_friction`` + ``force_offset``, each of
which the library tells apart on its own, also solved at the composite's own
switch width and alignment) by ``PAIR_REL_GAIN`` of the nominal's error;
otherwise the decomposition is named, and the report gives the other reading
(the asymmetric levels, or the offset the asymmetric levels imply) beside it.
"""

import copy
import itertools
import json
import math
import os
import time

import numpy as np
from scipy import optimize, signal
from scipy.io import loadmat

from rths_common import bagio, topics
from rths_common.columns import read_columns, read_header
from rths_common.timebase import sampling_rate_hz
from rths_discrepancy import effects as fx
from rths_discrepancy import reversals
from rths_discrepancy import signals as sg
from rths_discrepancy.io import write_csv as write_columns
from rths_discrepancy.report import _atomic_write

COLUMNS = ('time_s', 'displacement_m', 'force_N')
OPTIONAL = ('velocity_m_s',)
EFFECTS = ('coulomb_friction', 'asymmetric_friction', 'stribeck', 'force_offset',
           'cubic_stiffness', 'quadratic_damping', 'backlash', 'hysteresis', 'time_delay')
#: Parameter names and units of each effect (amplitudes, then the shape parameter).
PARAMS = {
    'coulomb_friction': (('F_c', 'N'), ('v_eps', 'm/s')),
    'asymmetric_friction': (('F_p', 'N'), ('F_n', 'N'), ('v_eps', 'm/s')),
    'stribeck': (('F_c', 'N'), ('F_s_minus_F_c', 'N'), ('v_s', 'm/s')),
    'force_offset': (('F_0', 'N'),),
    'cubic_stiffness': (('k3', 'N/m^3'),),
    'quadratic_damping': (('c2', 'N s^2/m^2'),),
    'backlash': (('k_b', 'N/m'), ('F_b', 'N'), ('b', 'm')),
    'hysteresis': (('alpha', 'N'), ('x_y', 'm')),
    'time_delay': (('tau', 's'),),
}
TRAIN_FRACTION = 0.6
MIN_SAMPLES = 200
ALIGN_SAMPLES = 1.5
#: The nominal's alignment (samples) from which the candidates start from none as well.
ALIGN_LEAN = 0.25
MIN_REL_GAIN = 0.05
PAIR_CUT = 0.2
PAIR_REL_GAIN = 0.02
UNEXPLAINED_LEFT = 0.5
#: A clearance this wide (of the displacement's spread) is no reading of friction.
CLEARANCE_MIN = 0.1
#: What friction through a clearance must explain of Coulomb friction's held-out error
#: where the reversals show no plateau (:func:`clearance_seen`).
CLEARANCE_GAIN = 0.5
#: The friction-through-play smoothing scales tried (x rms(v)); the data choose one.
BACKLASH_EPS = (1e-3, 3e-3, 1e-2, 3e-2)
#: The force reading's drift: its change over the record from the first sample (decide_drift).
DRIFT_PARAM = ('F_d', 'N')
#: Composite effects and their decomposition into elementary ones (the same law while sliding).
EQUIVALENT = {'asymmetric_friction': ('coulomb_friction', 'force_offset')}


# ---------------------------------------------------------------- input

def validate(data, source='data'):
    """Check the restoring-force columns; return float arrays and 'fs' (rths_common.timebase)."""
    missing = [c for c in COLUMNS if c not in data]
    if missing:
        raise ValueError(f'{source}: missing column(s) {", ".join(missing)}; the restoring-force '
                         f'scenario needs {", ".join(COLUMNS)} (optional {OPTIONAL[0]})')
    cols = COLUMNS + tuple(c for c in OPTIONAL if c in data)
    out = {c: np.asarray(data[c], float).ravel() for c in cols}
    n = out['time_s'].size
    for c in cols:
        if out[c].size != n:
            raise ValueError(f'{source}: column {c} has {out[c].size} values, time_s has {n}')
        if not np.all(np.isfinite(out[c])):
            i = int(np.argmax(~np.isfinite(out[c])))
            raise ValueError(f'{source}: column {c} has NaN/inf values, first at row {i}; '
                             'remove or interpolate them')
    if n < MIN_SAMPLES:
        raise ValueError(f'{source}: only {n} rows; the restoring-force scenario needs at least '
                         f'{MIN_SAMPLES} (a training and a later held-out part)')
    if np.std(out['displacement_m']) == 0 or np.std(out['force_N']) == 0:
        raise ValueError(f'{source}: displacement_m or force_N is constant; nothing to fit')
    # increasing and uniform within the printing; the rate the printed times imply
    out['fs'] = sampling_rate_hz(out['time_s'], source)
    return out


def load_csv(path):
    """Read a restoring-force CSV (header row; extra columns ignored)."""
    present = read_header(path)
    cols = read_columns(path, COLUMNS + tuple(c for c in OPTIONAL if c in present),
                        keep_nan=True, min_rows=0)
    return validate(cols, source=str(path))


def read_bag(bag):
    """Restoring-force columns of an rths run bag (channel 0; not yet validated).

    ``displacement_m`` is the measured actuator displacement and ``force_N`` the
    measured force the specimen returns to the structure (``/rths/measurement``),
    ``time_s`` the step over the run's ``fs_hz``.  Steps with a non-finite value
    (not applied) are dropped.
    """
    fs = bagio.sampling_rate(bag)
    data = bagio.step_arrays(bag, topics.MEASUREMENT, ('displacement', 'force'))
    if data['step'].size == 0:
        raise ValueError(f'{bag}: no {topics.MEASUREMENT} messages; is this an rths run bag?')
    x, f = data['displacement'][:, 0], data['force'][:, 0]
    ok = np.isfinite(x) & np.isfinite(f)
    return {'time_s': data['step'][ok] / fs, 'displacement_m': x[ok], 'force_N': f[ok]}


def write_csv(path, data):
    """Write the restoring-force columns of ``data`` (atomic)."""
    write_columns(path, data, COLUMNS + tuple(c for c in OPTIONAL if c in data))


def convert(kind, src):
    """Columns of the CSV contract from an original data file.

    ``kind`` 'emps': DATA_EMPS.mat of the EMPS benchmark (t [s], qm [m] motor
    position, vir [V] controller output, gtau [N/V]; force = gtau * vir).
    'mr-damper': a preprocessed MR-damper sinusoid test (whitespace columns
    t [s], x [mm], v [mm/s], F [N]).
    """
    if kind == 'emps':
        m = loadmat(src)
        for key in ('t', 'qm', 'vir', 'gtau'):
            if key not in m:
                raise ValueError(f'{src}: no variable {key!r}; expected DATA_EMPS.mat')
        return {'time_s': m['t'].ravel(), 'displacement_m': m['qm'].ravel(),
                'force_N': float(np.ravel(m['gtau'])[0]) * m['vir'].ravel()}
    if kind == 'mr-damper':
        d = np.loadtxt(src)
        if d.ndim != 2 or d.shape[1] < 4:
            raise ValueError(f'{src}: expected 4 columns t [s], x [mm], v [mm/s], F [N]')
        return {'time_s': d[:, 0], 'displacement_m': 1e-3 * d[:, 1],
                'velocity_m_s': 1e-3 * d[:, 2], 'force_N': d[:, 3]}
    raise ValueError(f'unknown data kind {kind!r}; use emps or mr-damper')


# ---------------------------------------------------------------- states

#: Highest cut-off of the states, as a fraction of the rate (the taper ends at 1.25 x it).
FC_MAX = 0.4
#: Central differences only while the band stays below this fraction of the rate.
CENTRAL_MAX = 0.05
#: Cut-offs tried between the displacement's band edge and the upper cut-off.
FC_GRID = 12
#: A higher cut-off is kept while its linear-fit residual stays within this fraction of the least
#: (a friction record with rests: the residuals of all cut-offs within 2 %, noise-level).
FC_TIE = 0.05
#: The best candidates (held-out criterion) that choose the cut-off in the end.
CUTOFF_TOP = 3
#: A record is periodic when it repeats to within this fraction of its spread (rms).
PERIOD_TOL = 0.05
DIFFERENTIATORS = ('spectral, whole periods', 'spectral, smoothing',
                   'butterworth, central differences')


def record_period(data):
    """Return the samples per period shared by displacement and force (None unless both repeat)."""
    p = sg.period(data['displacement_m'], tol=PERIOD_TOL)
    if p is None or sg.period(data['force_N'], tol=PERIOD_TOL) != p:
        return None
    return p


def whole_periods(data):
    """Return ``data`` cut to its whole periods (as is if it does not repeat) and the period."""
    p = record_period(data)
    if p is None:
        return data, None
    n = (data['force_N'].size // p) * p
    cut = {k: (v[:n] if isinstance(v, np.ndarray) else v) for k, v in data.items()}
    return cut, p


def _states_at(data, fc, periodic):
    """x, v, a of ``data`` band-limited at ``fc`` by the differentiator that fits it."""
    fs = data['fs']
    x_raw = data['displacement_m']
    out = {'fc': float(fc)}
    if periodic or fc > CENTRAL_MAX * fs:
        out['method'] = DIFFERENTIATORS[0 if periodic else 1]
        out.update(sg.spectral_states(x_raw, fs, fc, periodic))
        if 'velocity_m_s' in data:
            out['v'] = sg.spectral_derivative(data['velocity_m_s'], fs, 0, fc, periodic)
            out['a'] = sg.spectral_derivative(data['velocity_m_s'], fs, 1, fc, periodic)
        return out
    sos = signal.butter(4, fc, fs=fs, output='sos')

    def lp(y):
        return signal.sosfiltfilt(sos, y)

    x = lp(x_raw)
    v = lp(data['velocity_m_s']) if 'velocity_m_s' in data else lp(np.gradient(x, 1.0 / fs))
    a = lp(np.gradient(v, 1.0 / fs))
    out.update(x=x, v=v, a=a, method=DIFFERENTIATORS[2])
    return out


def _linear_residual(st, force):
    """Mean square residual of ``force`` on ``a, v, x, 1, t`` over the whole record (edges out).

    The whole record: the cut-off is the record's band, which a sweep or a stepped
    sine reaches only in its later part; no model is scored by it.
    """
    n = force.size
    core = slice(int(0.05 * n), n - int(0.05 * n))
    mat = np.column_stack([st['a'][core], st['v'][core], st['x'][core], np.ones(n)[core],
                           np.linspace(0.0, 1.0, n)[core]])
    scale = np.std(mat, axis=0)
    scale[scale == 0] = 1.0
    theta = np.linalg.lstsq(mat / scale, force[core], rcond=None)[0]
    return float(np.mean((force[core] - (mat / scale) @ theta) ** 2))


def smooth_states(data, periodic=False, fc=None):
    """x, v, a and the differentiator's cut-off fc and name (see the module doc).

    ``fc``: the cut-off the candidates chose (:func:`candidates_cutoff`) in place of
    the linear fit's, which is still reported (``fc_linear``, the residuals).
    """
    fs = data['fs']
    x_raw = data['displacement_m']
    f99 = max(sg.band_edge(x_raw, fs, 0.99), 10.0 * fs / x_raw.size)
    f99_force = sg.band_edge(data['force_N'], fs, 0.99)
    fc_max = float(np.clip(4.0 * f99_force, 10.0 * f99, FC_MAX * fs))
    # the cut-off chosen by the data: the record's own linear fit of the force on the
    # states at each cut-off of a grid from f99 to fc_max; noise differentiated past the
    # motion's band enters the regressors and raises that residual, a cut-off below the
    # band loses motion and raises it too; the highest cut-off within FC_TIE of the least
    # residual is taken (noise-free records keep fc_max)
    # (never below the band holding 99.9 % of the displacement's power: a nonlinear force
    # can favour dropping a small late motion, e.g. a sweep's high end, the states need)
    f_lo = min(max(f99, sg.band_edge(x_raw, fs, 0.999)), fc_max)
    grid = np.unique(np.concatenate([np.geomspace(f_lo, fc_max, FC_GRID), [fc_max]]))
    res = [(_linear_residual(_states_at(data, fc, periodic), data['force_N']), fc)
           for fc in grid]
    best = min(r for r, _ in res)
    fc_linear = max(f for r, f in res if r <= (1.0 + FC_TIE) * best)
    out = _states_at(data, fc_linear if fc is None else fc, periodic)
    out.update(f99=f99, f99_force=f99_force, fc_max=fc_max, fc_grid=[float(f) for f in grid],
               fc_linear=float(fc_linear), fc_residuals={f'{f:.4g}': r for r, f in res})
    return out


class Fit:
    """Shared data of the candidate fits: states, force, masks, scales.

    ``cutoff``: the states' cut-off [Hz] the candidates chose (:func:`candidates_cutoff`);
    None: the linear fit's (:func:`smooth_states`).
    """

    def __init__(self, data, cutoff=None):
        data, self.period = whole_periods(data)
        self.data = data
        self.fs = data['fs']
        self.t = data['time_s']
        self.f = data['force_N']
        self.st = smooth_states(data, periodic=self.period is not None, fc=cutoff)
        self.n = self.f.size
        n_tr = int(TRAIN_FRACTION * self.n)
        self.train = np.zeros(self.n, bool)
        self.train[int(0.02 * self.n):n_tr] = True   # skip the filters' edge transient
        self.test = np.zeros(self.n, bool)
        self.test[n_tr:int(0.98 * self.n)] = True
        # the same rows as slices: views where the masks would copy (the fits' inner loop)
        self._rows = ((self.train, slice(int(0.02 * self.n), n_tr)),
                      (self.test, slice(n_tr, int(0.98 * self.n))))
        self.scales = {'x': float(np.std(self.st['x'])), 'v': float(np.std(self.st['v']))}
        x = self.st['x'] - np.mean(self.st['x'])
        spec = np.abs(np.fft.rfft(x)) ** 2
        f = np.fft.rfftfreq(x.size, 1.0 / self.fs)
        self.f_dom = float(f[1 + int(np.argmax(spec[1:]))])
        self.max_delay = max(0.1 / self.f_dom, 3.0 / self.fs)
        self.align_max = ALIGN_SAMPLES / self.fs
        # white noise is read above the states' band (fs / 4 for slow records)
        self.noise_from = min(max(0.25 * self.fs, 1.25 * self.st['fc']), 0.45 * self.fs)
        self._bw = {}
        self.backlash_eps = 1e-2    # x rms(v); chosen by the data in select()
        # the force reading's drift from the record's start (0 to 1 over the record); a
        # nuisance term of every model once the data decide it (select(), decide_drift())
        self.ramp = np.linspace(0.0, 1.0, self.n)
        self.drift = False

    def shape_bounds(self, name):
        """Search interval of the shape parameter of ``name`` (from the data's own scales)."""
        sv, sx = self.scales['v'], self.scales['x']
        return {'coulomb_friction': (1e-4 * sv, 0.03 * sv),
                'asymmetric_friction': (1e-4 * sv, 0.03 * sv),
                'stribeck': (0.02 * sv, 1.0 * sv),
                'backlash': (1e-3 * sx, 0.8 * sx),
                'hysteresis': (1e-3 * sx, 1.0 * sx),
                'time_delay': (-self.max_delay, self.max_delay)}.get(name)

    def columns(self, name, p, st):
        """Regressor columns of effect ``name`` with shape parameter ``p`` on states ``st``."""
        x, v = st['x'], st['v']
        if name == 'coulomb_friction':
            return [np.tanh(v / p)]
        if name == 'asymmetric_friction':
            t = np.tanh(v / p)
            return [np.maximum(t, 0.0), np.minimum(t, 0.0)]
        if name == 'stribeck':
            t = np.tanh(v / (1e-2 * self.scales['v']))
            return [t, np.exp(-(v / p) ** 2) * t]
        if name == 'force_offset':
            return [np.ones(self.n)]
        if name == 'cubic_stiffness':
            xc = x - np.mean(x)
            return [xc ** 3]
        if name == 'quadratic_damping':
            return [v * np.abs(v)]
        if name == 'backlash':
            xc = x - np.mean(x)
            z = fx.play(x, p)           # the far side of the clearance
            e = x - z
            # sliding at this sample: at the clearance's edge, moving into it (a
            # difference of z would smear each engagement over a neighbouring sample)
            edge = (np.abs(e) >= p * (1.0 - 1e-9)) & (np.sign(e) == np.sign(v))
            return [np.sign(xc) * np.maximum(np.abs(xc) - p, 0.0),
                    edge * np.tanh(v / (self.backlash_eps * self.scales['v']))]
        if name == 'hysteresis':
            key = (round(p, 15), id(st))
            if key not in self._bw:
                if len(self._bw) > 256:
                    self._bw.clear()
                self._bw[key] = fx.bouc_wen(x, p)
            return [self._bw[key]]
        return []

    def on_states(self, st):
        """Return a copy of this fit that solves on the states ``st`` (scales kept)."""
        other = copy.copy(self)
        other.st = st
        other._bw = {}
        other._shift = {}
        return other

    def states_at(self, tau):
        """States shifted so that the model's force lags them by ``tau`` [s]."""
        if tau == 0.0:
            return self.st
        if not hasattr(self, '_shift'):
            self._shift = {}
        key = round(tau * self.fs, 6)
        if key not in self._shift:
            if len(self._shift) > 64:
                self._shift.clear()
            self._shift[key] = {k: fx.delay(self.st[k], tau, self.fs) for k in ('x', 'v', 'a')}
        return self._shift[key]

    def design(self, names, shapes, tau):
        """Regressor matrix and column labels of the nominal + ``names``."""
        st = self.states_at(tau)
        cols = [st['a'], st['v'], st['x']]
        labels = [('nominal', 'm'), ('nominal', 'c'), ('nominal', 'k')]
        for name in names:
            if name == 'time_delay':
                continue
            new = self.columns(name, shapes.get(name), st)
            cols += new
            labels += [(name, PARAMS[name][j][0]) for j in range(len(new))]
        if self.drift:
            cols.append(self.ramp)
            labels.append(('drift', DRIFT_PARAM[0]))
        return np.column_stack(cols), labels

    def solve(self, names, shapes, tau):
        """Least squares on the training part; return (theta, labels, prediction)."""
        mat, labels = self.design(names, shapes, tau)
        tr = self.rows(self.train)
        scale = np.std(mat[tr], axis=0)
        scale[scale == 0] = 1.0
        a = mat[tr] / scale
        try:   # normal equations on unit-scaled columns (a few columns, many rows: fast)
            theta = np.linalg.solve(a.T @ a, a.T @ self.f[tr]) / scale
        except np.linalg.LinAlgError:
            theta = np.linalg.lstsq(a, self.f[tr], rcond=None)[0] / scale
        return theta, labels, mat @ theta

    def rows(self, mask):
        """Return ``mask`` as a slice if it is the training or the held-out mask."""
        for m, rows in self._rows:
            if mask is m:
                return rows
        return mask

    def mse(self, pred, mask):
        """Mean square force error on ``mask``."""
        rows = self.rows(mask)
        return float(np.mean((self.f[rows] - pred[rows]) ** 2))


def _refine_alignment(fit, names, shapes, tau):
    """Two Gauss-Newton steps of the alignment (within the band) for fixed shapes."""
    h = fit.align_max
    for _ in range(2):
        theta, _, pred = fit.solve(names, shapes, tau)
        d = -np.gradient(pred, 1.0 / fit.fs)
        tr = fit.train
        r = fit.f[tr] - pred[tr]
        den = float(np.dot(d[tr], d[tr]))
        if den <= 0:
            break
        tau = float(np.clip(tau + np.dot(d[tr], r) / den, -h, h))
    return tau


def fit_candidate(fit, names, align0):
    """Fit ``names`` (shape parameters by search, then the alignment); return a result dict."""
    shaped = [n for n in names if fit.shape_bounds(n) is not None]
    delay = 'time_delay' in names

    def outside_band(tau):
        # a delay inside the alignment band is an alignment, not a time_delay
        h = fit.align_max
        return tau if abs(tau) >= h else math.copysign(h, tau if tau else 1.0)

    def cost(ps):
        shapes = dict(zip(shaped, ps, strict=True))
        tau = outside_band(shapes.pop('time_delay')) if delay else align0
        return fit.mse(fit.solve(names, shapes, tau)[2], fit.train)

    best = []
    if len(shaped) == 1:
        lo, hi = fit.shape_bounds(shaped[0])
        grid = np.linspace(lo, hi, 41) if shaped[0] == 'time_delay' else np.geomspace(lo, hi, 20)
        costs = [cost([g]) for g in grid]
        i = int(np.argmin(costs))
        a, b = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
        res = optimize.minimize_scalar(lambda q: cost([q]), bounds=(a, b), method='bounded',
                                       options={'xatol': 1e-4 * (b - a) + 1e-15, 'maxiter': 25})
        best = [float(res.x)] if res.fun <= costs[i] else [float(grid[i])]
    elif shaped:
        grids = [np.linspace(*fit.shape_bounds(n), 11) if n == 'time_delay'
                 else np.geomspace(*fit.shape_bounds(n), 7) for n in shaped]
        pts = list(itertools.product(*grids))
        costs = [cost(p) for p in pts]
        p0 = np.array(pts[int(np.argmin(costs))], float)
        lo = np.array([fit.shape_bounds(n)[0] for n in shaped])
        hi = np.array([fit.shape_bounds(n)[1] for n in shaped])

        step = np.maximum(np.abs(p0), 0.05 * (hi - lo))

        def inside(z):
            return np.clip(p0 + z * step, lo, hi)

        res = optimize.minimize(lambda z: cost(inside(z)),
                                np.zeros(len(shaped)), method='Nelder-Mead',
                                options={'initial_simplex': np.vstack(
                                    [np.zeros(len(shaped)), 0.1 * np.eye(len(shaped))]),
                                    'xatol': 1e-4, 'fatol': 0.0, 'maxiter': 40})
        best = list(inside(res.x)) if res.fun < min(costs) else list(p0)
    shapes = dict(zip(shaped, best, strict=True))
    tau = outside_band(shapes.pop('time_delay')) if delay else None
    if not delay:
        tau = _refine_alignment(fit, names, shapes, align0)
    return candidate(fit, names, shapes, tau)


def candidate(fit, names, shapes, tau):
    """Return the result dict of ``names`` with these shapes and alignment (amplitudes solved)."""
    theta, labels, pred = fit.solve(names, shapes, tau)
    extra = 1 if 'backlash' in names else 0     # its friction's v_eps, chosen by the data
    return {'names': list(names), 'shapes': shapes, 'tau': tau, 'theta': theta,
            'labels': labels, 'pred': pred, 'mse_test': fit.mse(pred, fit.test),
            'mse_train': fit.mse(pred, fit.train),
            'backlash_eps': fit.backlash_eps * fit.scales['v'] if extra else None,
            'p': len(theta) + len(shapes) + 1 + extra}


def alignment_starts(fit, nominal_tau):
    """Return the alignments [s] the candidates' fits start from.

    The nominal's own alignment, refined per candidate (:func:`_refine_alignment`).
    A linear model leans on the alignment to take up a force it lacks: a history
    (a loop, a clearance) lags the motion, and the nominal's alignment moves by a
    sizeable part of a sample (unseen-battery seeds 41, 42: every record with
    friction through play or a Bouc-Wen loop at 0.3-1.5 samples, the band's edge; every
    other record within 0.25 samples).  A clearance or a yield displacement searched
    at that alignment is off by as much as the path travels in it (a friction damper
    with play at 3300 Hz: +1.5 samples, the clearance 1.90 mm, held-out NRMSE 0.145;
    from the record as given, 2.13 mm and 0.031, the generator's 2.12 mm).  Where the
    nominal's alignment is ``ALIGN_LEAN`` of a sample or more, the record as given (0)
    is a start as well, and :func:`fit_from` keeps the fit of the lower training error.
    """
    if abs(nominal_tau) * fit.fs >= ALIGN_LEAN:
        return (nominal_tau, 0.0)
    return (nominal_tau,)


def fit_from(fit, names, starts):
    """Fit ``names`` from each alignment of ``starts``; return the fit of least training error."""
    if 'time_delay' in names:      # its lag is searched over the whole delay range
        starts = starts[:1]
    fits = [fit_candidate(fit, names, a) for a in starts]
    return min(fits, key=lambda c: c['mse_train'])


def choose_backlash_eps(fit, starts):
    """Set ``fit.backlash_eps`` to the scale of :data:`BACKLASH_EPS` that fits best.

    The friction through a clearance switches on and off with each engagement; how
    sharply is the data's (a damper's slider, a joint's bolt): the backlash candidate
    with the force's constant (``force_offset``: a load cell's zero, a spring's force
    at a displaced centre, which alone would bend the clearance fitted) is fitted at
    each scale and the lowest training error chooses.  Returns the training mean
    square error per scale.
    """
    errs = {}
    for eps in BACKLASH_EPS:
        fit.backlash_eps = eps
        errs[eps] = fit_from(fit, ['force_offset', 'backlash'], starts)['mse_train']
    fit.backlash_eps = min(errs, key=errs.get)
    return errs


def _params(cand):
    """Parameters of the effects of ``cand`` ({effect: {name: value, 'unit': ...}})."""
    out = {}
    amps = {}
    for (name, par), val in zip(cand['labels'], cand['theta'], strict=True):
        amps.setdefault(name, {})[par] = float(val)
    for name in cand['names']:
        spec = dict(PARAMS[name])
        entry = dict(amps.get(name, {}))
        if name == 'time_delay':
            entry['tau'] = float(cand['tau'])
        elif name in cand['shapes']:
            shape_name = PARAMS[name][-1][0]
            entry[shape_name] = float(cand['shapes'][name])
        if name == 'backlash' and cand.get('backlash_eps') is not None:
            entry['v_eps'] = float(cand['backlash_eps'])
            spec['v_eps'] = 'm/s'
        entry['unit'] = {k: spec[k] for k in entry}
        out[name] = entry
    return out


def select(fit, progress=None, count=None):
    """Fit the nominal, every effect and every pair; decide (see the module doc).

    ``count(done, total)`` gets the candidates fitted so far.
    """
    say = progress or (lambda msg: None)
    nominal, cands, unseen, floor = _fit_all(fit, count)
    say(f'fitted {len(cands) + len(unseen)} candidates')
    drift = decide_drift(fit, nominal, cands)
    if drift['decided']:
        fit.drift = True
        say(f"force drift over the record {drift['F_d']:.4g} (held-out information criterion "
            f"{drift['ic_without']:.1f} -> {drift['ic_with']:.1f} on {drift['read_on']}): "
            'a term of every model; candidates fitted again')
        nominal, cands, unseen, floor = _fit_all(fit, count)
    ic = _ic(fit)
    ics = {k: ic(c) for k, c in cands.items()}
    ic_none = ic(nominal)
    m0 = nominal['mse_test']
    # the pair margins are read against the linear model with its constant: an offset
    # (a transducer's zero, volts about a bias) is as large as its units make it and
    # must not decide whether a second effect is worth its name
    m_lin = min(m0, cands['force_offset']['mse_test'])
    singles = [k for k in cands if '+' not in k]
    pairs = [k for k in cands if '+' in k]
    best1 = min(singles, key=lambda k: ics[k])
    best2 = min(pairs, key=lambda k: ics[k])
    choice = best1
    # excess over the white-noise floor (periodogram of the nominal residual above the band)
    e1 = cands[best1]['mse_test'] - floor
    e2 = cands[best2]['mse_test'] - floor
    more = cands[best2]['p'] > cands[best1]['p']
    big = e1 - e2 > PAIR_REL_GAIN * (m_lin - floor)
    if ics[best2] < ics[best1] and (not more or (e2 < (1.0 - PAIR_CUT) * e1 and big)):
        choice = best2
    margin = PAIR_REL_GAIN * (m_lin - floor)
    choice, equivalence = _prefer_decomposition(fit, cands, choice, margin)
    choice, friction_law = _prefer_coulomb(cands, choice, floor, margin)
    ics = {k: ic(c) for k, c in cands.items()}
    choice, play = _play_or_loop(fit, cands, choice, ics, ic_none)
    mc = cands[choice]['mse_test']
    if ics[choice] >= ic_none or m0 - mc < MIN_REL_GAIN * m0:
        decision = 'none'
    elif mc - floor > UNEXPLAINED_LEFT * (m0 - floor):
        decision = 'unexplained'
    else:
        decision = choice
    return {'decision': decision, 'choice': choice, 'nominal': nominal, 'cands': cands,
            'ic': ics, 'ic_none': ic_none, 'equivalence': equivalence, 'play_or_loop': play,
            'clearance_not_seen': unseen, 'drift': drift, 'friction_law': friction_law}


def _prefer_coulomb(cands, choice, floor, margin):
    """Keep Coulomb friction where the Stribeck law's extra terms explain little beyond it.

    The Stribeck law holds Coulomb friction (``F_s = F_c``); its velocity-weakening
    term, a bump of width ``v_s`` about zero velocity, also bends any misfit at the
    reversals (a switch the band-limited states smear) and wins the criterion by a
    few per cent of the error on a Coulomb record.  Like a pair over a single
    effect, it is named only if it removes ``PAIR_CUT`` of what the same model with
    Coulomb friction in its place leaves above the white-noise ``floor``, and more
    than ``margin`` (``PAIR_REL_GAIN`` of the linear model's error).  Returns
    (choice, evidence or None).
    """
    names = cands[choice]['names']
    if 'stribeck' not in names:
        return choice, None
    alt = label([n for n in names if n != 'stribeck'] + ['coulomb_friction'])
    if alt not in cands:
        return choice, None
    e_s = cands[choice]['mse_test'] - floor
    e_c = cands[alt]['mse_test'] - floor
    kept = bool(e_s < (1.0 - PAIR_CUT) * e_c and e_c - e_s > margin)
    return (choice if kept else alt), {
        'stribeck': choice, 'coulomb': alt, 'excess_mse_stribeck': float(e_s),
        'excess_mse_coulomb': float(e_c), 'cut_needed': PAIR_CUT, 'margin': float(margin),
        'stribeck_kept': kept}


def _ic(fit):
    """Held-out information criterion ``N ln(mse) + p ln N`` of a candidate (a function)."""
    n_te = int(fit.test.sum())

    def ic(c):
        return n_te * math.log(max(c['mse_test'], 1e-300)) + c['p'] * math.log(n_te)
    return ic


def _fit_all(fit, count=None):
    """Fit the nominal, every effect and every pair (friction laws of one kind not combined).

    Returns (nominal, candidates, candidates whose clearance the record does not show
    (dropped), the white-noise floor of the nominal's residual).
    """
    nominal = fit_candidate(fit, [], 0.0)
    starts = alignment_starts(fit, nominal['tau'])
    friction = {'coulomb_friction', 'asymmetric_friction', 'stribeck'}
    todo = [[name] for name in EFFECTS] + [
        [a, b] for a, b in itertools.combinations(EFFECTS, 2) if not {a, b} <= friction]
    choose_backlash_eps(fit, starts)
    cands = {}
    for names in todo:
        cands['+'.join(names)] = fit_from(fit, names, starts)
        if count:
            count(len(cands), len(todo))
    floor = sg.noise_variance(fit.f - nominal['pred'], fit.fs, fit.noise_from)
    unseen = [k for k, c in cands.items()
              if 'backlash' in c['names'] and not clearance_seen(fit, c, cands, floor)]
    for k in unseen:
        del cands[k]
    return nominal, cands, unseen, floor


def candidates_cutoff(fit, sel):
    """Return the states' cut-off [Hz] the best candidates choose, and the evidence.

    The ``CUTOFF_TOP`` candidates of the lowest held-out criterion, their shape
    parameters and alignments kept, are solved again (amplitudes only) on the states
    at each cut-off of the linear fit's grid; the highest cut-off within ``FC_TIE`` of
    the least held-out error of any of them is taken (seeds 20261203-05, judged before:
    the linear fit took 164, 55 and 494 Hz on three friction records with 2.3, 3.0 and
    0.3 % noise where these errors were 3.1, 2.5 and 125 times their least, and the
    Stribeck law or Coulomb friction was not named).  The evidence: the cut-offs, the
    candidates and the held-out error per cut-off.
    """
    ic = sel['ic']
    top = sorted(ic, key=ic.get)[:CUTOFF_TOP]
    periodic = fit.period is not None
    errors = {}
    for fc in fit.st['fc_grid']:
        trial = fit.on_states(_states_at(fit.data, fc, periodic))
        errors[fc] = min(trial.mse(trial.solve(c['names'], c['shapes'], c['tau'])[2],
                                   trial.test) for c in (sel['cands'][k] for k in top))
    least = min(errors.values())
    fc = max(f for f, e in errors.items() if e <= (1.0 + FC_TIE) * least)
    return fc, {'candidates': top,
                'heldout_mse_per_cutoff': {f'{f:.4g}': e for f, e in errors.items()}}


def decide_drift(fit, nominal, cands):
    """Decide whether the force reading drifts: a term ``F_d (t - t_0) / T`` of every model.

    A load cell's zero moves slowly over a test (temperature, creep of the bridge);
    labs zero it before the test, so the drift is read from the record's first sample,
    a straight line over the record (:data:`DRIFT_PARAM`).  The record decides: the
    candidate of the lowest held-out information criterion (or the nominal) is fitted
    again with the line, its shape parameters and alignment kept; the drift is a term
    of every model when the line, fitted on the training part and carried over the
    held-out part, lowers that criterion.  A drift is a property of the transducer,
    not of the specimen: it is never named as an effect, and without it a slow line
    passes for a ``force_offset`` (its mean) or spoils the gap of the effect that is
    there.  Returns the evidence (``decided``, ``F_d`` [N], the criteria).
    """
    ic = _ic(fit)
    pool = dict(cands, nominal=nominal)
    key = min(pool, key=lambda k: ic(pool[k]))
    best = pool[key]
    fit.drift = True
    try:
        theta, labels, pred = fit.solve(best['names'], best['shapes'], best['tau'])
    finally:
        fit.drift = False
    with_drift = {'mse_test': fit.mse(pred, fit.test), 'p': best['p'] + 1}
    f_d = float(theta[labels.index(('drift', DRIFT_PARAM[0]))])
    return {'decided': bool(ic(with_drift) < ic(best)), 'read_on': key, 'F_d': f_d,
            'rate_N_per_s': f_d / float(fit.t[-1] - fit.t[0]),
            'ic_without': ic(best), 'ic_with': ic(with_drift)}


def clearance_seen(fit, cand, cands=None, floor=0.0):
    """Tell whether the clearance ``cand`` fits shows in the record (see :mod:`.reversals`).

    A clearance of half-width ``b`` crossed after each reversal leaves a near-zero-force
    stretch at least ``b`` wide that does not grow with the amplitude.  Where the record
    shows none, a small ``b`` is only another reading of Coulomb friction (and of an
    offset, through the spring's centre): the candidate is not offered.

    A spring behind a clearance (the F-16's joint: no reversal plateau, the force is a
    function of the position) shows instead as a wide clearance, at least
    ``CLEARANCE_MIN`` of the displacement's spread, whose spring carries more of the
    candidate's force than its friction does: no reading of Coulomb friction.

    Under a broadband excitation most reversals are small and the plateaus are not
    read; there a wide clearance shows on the held-out part instead (``cands`` given):
    friction that stops for the clearance after each reversal must explain at least
    ``CLEARANCE_GAIN`` of what Coulomb friction in its place leaves above the noise
    ``floor`` (a Coulomb record fits best with ``b`` near zero, a smooth loop better
    with Coulomb friction than with the clearance's on-off law).
    """
    b = cand['shapes']['backlash']
    amp = {par: v for (g, par), v in zip(cand['labels'], cand['theta'], strict=True)
           if g == 'backlash'}
    cols = fit.columns('backlash', b, fit.st)
    wide = b >= CLEARANCE_MIN * fit.scales['x']
    if wide and np.std(amp['k_b'] * cols[0]) >= np.std(amp['F_b'] * cols[1]):
        return True
    if wide and cands is not None:
        alt = label([n for n in cand['names'] if n != 'backlash'] + ['coulomb_friction'])
        if alt in cands:
            left = cand['mse_test'] - floor
            if left <= (1.0 - CLEARANCE_GAIN) * (cands[alt]['mse_test'] - floor):
                return True
    ev = play_evidence(fit, cand)
    width, growth = ev.get('plateau_width_median'), ev.get('growth')
    return bool(width is not None and width >= b
                and (growth is None or growth < reversals.MAX_GROWTH))


def play_evidence(fit, cand):
    """Play-versus-loop evidence (:mod:`.reversals`) on the force ``cand``'s m, c, k leave."""
    th = {par: v for (g, par), v in zip(cand['labels'], cand['theta'], strict=True)
          if g == 'nominal'}
    st = fit.st
    r = fit.f - (th['m'] * st['a'] + th['c'] * st['v'] + th['k'] * st['x'])
    for (g, _), v in zip(cand['labels'], cand['theta'], strict=True):
        if g == 'drift':
            r = r - v * fit.ramp
    return reversals.evidence(st['x'], r)


def _play_or_loop(fit, cands, choice, ics, ic_none):
    """Name backlash, not hysteresis, where the record shows play after its reversals.

    Read on the choice's own m, c, k when it holds hysteresis or backlash; a choice
    holding hysteresis on a record that shows play is replaced by the same effects
    with backlash in its place (if that candidate beats the nominal; fitted here when it
    is no candidate yet: a choice of three effects, e.g. the decomposition of
    ``asymmetric_friction+hysteresis``, has no counterpart among the pairs).  Returns
    (choice, evidence or None).
    """
    names = cands[choice]['names']
    if not {'hysteresis', 'backlash'} & set(names):
        return choice, None
    ev = play_evidence(fit, cands[choice])
    ev['read_on'] = choice
    if 'hysteresis' in names and ev['play']:
        alt = label([n for n in names if n != 'hysteresis'] + ['backlash'])
        if alt not in cands:
            cands[alt] = fit_candidate(fit, [n for n in EFFECTS if n in alt.split('+')],
                                       cands[choice]['tau'] if 'time_delay' not in names
                                       else 0.0)
            ics[alt] = _ic(fit)(cands[alt])
        if ics[alt] < ic_none:
            ev['replaced'] = {choice: alt}
            return alt, ev
    return choice, ev


def label(names):
    """Candidate key of the effects ``names`` ('a+b' in :data:`EFFECTS` order)."""
    return '+'.join(sorted(set(names), key=EFFECTS.index))


def _prefer_decomposition(fit, cands, choice, margin):
    """Replace a composite effect of ``choice`` by its elementary decomposition unless told apart.

    The composite stays only if its held-out mean square error is lower than the
    decomposition's by more than ``margin``.  Returns (choice, evidence or None);
    the decomposition is fitted (and added to ``cands``) if it was not a candidate.
    It is also solved at the composite's own switch width and alignment (the lower
    held-out error of the two is its): so set, the two readings differ only where
    the velocity rests, and a difference elsewhere is the fits', not the record's
    (seed 20261205's Coulomb multisine, no held-out sample at rest: asymmetric
    friction was told apart by 1.29 against a margin of 1.00, from the two fits'
    switch widths and alignments).
    """
    names = cands[choice]['names']
    composite = [n for n in names if n in EQUIVALENT]
    if not composite:
        return choice, None
    parts = [p for n in names for p in (EQUIVALENT.get(n) or (n,))]
    key = label(parts)
    ordered = [n for n in EFFECTS if n in parts]
    if key not in cands:
        cands[key] = fit_candidate(fit, ordered, cands[choice]['tau']
                                   if 'time_delay' not in names else 0.0)
    shapes = {('coulomb_friction' if n in EQUIVALENT else n): v
              for n, v in cands[choice]['shapes'].items()}
    same = candidate(fit, ordered, shapes, cands[choice]['tau'])
    if same['mse_test'] < cands[key]['mse_test']:
        cands[key] = same
    diff = cands[key]['mse_test'] - cands[choice]['mse_test']
    told_apart = diff > margin
    v_eps = cands[choice]['shapes'].get(composite[0])
    rest = float(np.mean(np.abs(fit.st['v'][fit.test]) < v_eps)) if v_eps else None
    evidence = {'composite': choice, 'decomposition': key, 'told_apart': bool(told_apart),
                'heldout_mse_difference': float(diff), 'margin': float(margin),
                'heldout_fraction_at_rest': rest}
    return (choice if told_apart else key), evidence


def other_reading(params):
    """Return the same sliding law in the other decomposition (see :data:`EQUIVALENT`).

    Coulomb friction ``F_c`` with an offset ``F_0`` reads as asymmetric levels
    ``F_p = F_c + F_0``, ``F_n = F_c - F_0``; asymmetric levels read as
    ``F_c = (F_p + F_n) / 2`` with the offset ``(F_p - F_n) / 2`` (plus any fitted
    ``F_0``).  Empty when ``params`` hold neither.
    """
    if 'asymmetric_friction' in params:
        fp, fn = params['asymmetric_friction']['F_p'], params['asymmetric_friction']['F_n']
        f0 = params.get('force_offset', {}).get('F_0', 0.0)
        return {'coulomb_friction': {'F_c': 0.5 * (fp + fn), 'unit': {'F_c': 'N'}},
                'force_offset': {'F_0': 0.5 * (fp - fn) + f0, 'unit': {'F_0': 'N'}}}
    if 'coulomb_friction' in params and 'force_offset' in params:
        fc, f0 = params['coulomb_friction']['F_c'], params['force_offset']['F_0']
        return {'asymmetric_friction': {'F_p': fc + f0, 'F_n': fc - f0,
                                        'unit': {'F_p': 'N', 'F_n': 'N'}}}
    return {}


def _defence(fit, sel):
    """Held-out evidence for the winner against its closest rival of another kind."""
    c = sel['cands']
    groups = {'hysteresis': [k for k in c if 'hysteresis' in k],
              'delayed_law': [k for k in c if 'time_delay' in k and 'hysteresis' not in k]}
    out = {}
    for g, keys in groups.items():
        if keys:
            k = min(keys, key=lambda k: sel['ic'][k])
            out[g] = {'candidate': k, 'heldout_nrmse': sg.nrmse(fit.f, c[k]['pred'], fit.test),
                      'information_criterion': sel['ic'][k]}
    return out


def run(data, out_dir=None, progress=None, plots=True, source=None, count=None):
    """Run the restoring-force workflow on validated ``data``; return result.json's dict.

    ``progress(text)`` gets the steps, ``count(done, total)`` the candidates fitted.
    """
    if 'fs' not in data:
        data = validate(data)
    say = progress or (lambda msg: None)
    fit = Fit(data)
    say(f"restoring force: {fit.n} samples at {fit.fs:g} Hz; states by "
        f"{fit.st['method']} (cut-off {fit.st['fc']:.3g} Hz); training {TRAIN_FRACTION:.0%}, "
        'held out the rest')
    sel = select(fit, progress=say, count=count)
    fc, cutoff = candidates_cutoff(fit, sel)
    if fc != fit.st['fc']:
        say(f"the best candidates fit the held-out force best on states cut at {fc:.3g} Hz: "
            'candidates fitted again')
        fit = Fit(data, cutoff=fc)
        sel = select(fit, progress=say, count=count)
    nom = sel['nominal']
    win = sel['cands'][sel['choice']]
    named = sel['decision'] not in ('none', 'unexplained')
    after = win if named else nom
    te = fit.test
    before = sg.nrmse(fit.f, nom['pred'], te)
    aft = sg.nrmse(fit.f, after['pred'], te)
    noise = math.sqrt(sg.noise_variance(fit.f - after['pred'], fit.fs, fit.noise_from))
    noise /= float(np.std(fit.f[te]))
    den = before ** 2 - noise ** 2
    model = {par: float(v) for (g, par), v in zip(after['labels'], after['theta'], strict=True)
             if g == 'nominal'}
    align = after['tau'] if 'time_delay' not in after['names'] else 0.0
    result = {
        'scenario': 'restoring-force',
        'source': source,
        'effect': sel['decision'],
        'parameters': _params(win) if named else {},
        'model_parameters': {'m': model['m'], 'c': model['c'], 'k': model['k'],
                             'unit': {'m': 'kg', 'c': 'N s/m', 'k': 'N/m'}},
        'nominal_parameters': {par: float(v) for (_, par), v in zip(
            nom['labels'], nom['theta'], strict=True)},
        'nrmse_before': before,
        'nrmse_after': aft,
        'nrmse_noise': noise,
        'gap_closed': float((before ** 2 - aft ** 2) / den) if den > 0 else 0.0,
        'alignment_s': float(align),
        'alignment_samples': float(align * fit.fs),
        'alignment_band_samples': ALIGN_SAMPLES,
        'force_drift': sel['drift'],
        'displacement_mean_m': float(np.mean(data['displacement_m'])),
        'best_candidate': sel['choice'],
        'candidates': {k: sg.nrmse(fit.f, c['pred'], te) for k, c in sel['cands'].items()},
        'candidates_parameters': {k: _params(c) for k, c in sel['cands'].items()},
        'information_criterion': sel['ic'],
        'information_criterion_none': sel['ic_none'],
        'held_out_evidence': _defence(fit, sel),
        'equivalence': sel['equivalence'],
        'play_or_loop': sel['play_or_loop'],
        'friction_law': sel['friction_law'],
        'clearance_not_seen': sel['clearance_not_seen'],
        'equivalent_reading': other_reading(_params(win)) if named else {},
        'smoothing_differentiator': {
            'method': fit.st['method'], 'period_samples': fit.period,
            'cutoff_hz': fit.st['fc'], 'cutoff_max_hz': fit.st['fc_max'],
            'cutoff_linear_fit_hz': fit.st['fc_linear'],
            'linear_residual_per_cutoff': fit.st['fc_residuals'],
            'cutoff_candidates': cutoff['candidates'],
            'candidates_heldout_mse_per_cutoff': cutoff['heldout_mse_per_cutoff'],
            'displacement_band_99_hz': fit.st['f99'],
            'force_band_99_hz': fit.st['f99_force'],
            'velocity': 'measured (smoothed)' if 'velocity_m_s' in data else 'differentiated'},
        'train_fraction': TRAIN_FRACTION,
        'sample_rate_hz': fit.fs,
        'samples': fit.n,
    }
    say(f"effect: {result['effect']}  held-out force NRMSE {before:.4f} -> {aft:.4f}; "
        f"alignment {result['alignment_samples']:+.2f} samples")
    if out_dir is not None:
        _write(out_dir, result, fit, nom['pred'], after['pred'], plots)
    return result


def _write(out_dir, result, fit, pred0, pred1, plots):
    os.makedirs(out_dir, exist_ok=True)
    files = _plots(out_dir, fit, pred0, pred1) if plots else {}
    _atomic_write(os.path.join(out_dir, 'report.md'), markdown(result, files))
    _atomic_write(os.path.join(out_dir, 'result.json'), json.dumps(result, indent=2))


def _plots(out_dir, fit, pred0, pred1):

    # lazy: start-up cost: matplotlib (~0.5 s), which this module needs only here
    import matplotlib
    matplotlib.use('Agg')
    # lazy: start-up cost: matplotlib (~0.5 s), which this module needs only here
    import matplotlib.pyplot as plt
    te = fit.test
    x, v = fit.st['x'][te], fit.st['v'][te]
    fig, ax = plt.subplots(2, 2, figsize=(9, 7), sharey=True)
    for j, (pred, lab) in enumerate(((pred0, 'before: linear m a + c v + k x'),
                                     (pred1, 'after: updated model'))):
        ax[j, 0].plot(x, fit.f[te], ',', color='0.5', label='measured')
        ax[j, 0].plot(x, pred[te], ',', color='C3', label='model')
        ax[j, 1].plot(v, fit.f[te], ',', color='0.5')
        ax[j, 1].plot(v, pred[te], ',', color='C3')
        ax[j, 0].set_ylabel(f'force [N]\n{lab}', fontsize=8)
    ax[1, 0].set_xlabel('displacement [m]')
    ax[1, 1].set_xlabel('velocity [m/s]')
    ax[0, 0].legend(markerscale=20, fontsize=8)
    fig.suptitle('restoring-force surface, held-out part (grey measured, red model)')
    fig.tight_layout()
    files = {'surface': 'restoring_force.png'}
    fig.savefig(os.path.join(out_dir, files['surface']), dpi=90)
    plt.close(fig)
    fig, ax = plt.subplots(2, 1, figsize=(9, 5), sharex=True)
    ax[0].plot(fit.t, fit.f, lw=0.5, color='0.4', label='measured')
    ax[0].plot(fit.t, pred1, lw=0.5, color='C3', label='updated model')
    ax[0].axvline(fit.t[np.argmax(te)], color='k', ls=':', lw=0.8)
    ax[0].set_ylabel('force [N]')
    ax[0].legend(fontsize=8, loc='upper right')
    ax[1].plot(fit.t, np.where(te, fit.f - pred0, np.nan), lw=0.5, label='before (held-out)')
    ax[1].plot(fit.t, np.where(te, fit.f - pred1, np.nan), lw=0.5, label='after (held-out)')
    ax[1].set_ylabel('force residual [N]')
    ax[1].set_xlabel('time [s]')
    ax[1].legend(fontsize=8, loc='upper right')
    fig.tight_layout()
    files['residuals'] = 'force_residuals.png'
    fig.savefig(os.path.join(out_dir, files['residuals']), dpi=90)
    plt.close(fig)
    return files


def markdown(result, files):
    """Return the report.md text of the restoring-force scenario."""
    lines = ['# Discrepancy report (restoring force)', '']
    if result.get('source'):
        lines += [f"Record: {result['source']}", '']
    lines += [f"**Effect: `{result['effect']}`**", '']
    for name, par in result['parameters'].items():
        vals = ', '.join(f"{k} = {v:.5g} {par['unit'][k]}" for k, v in par.items() if k != 'unit')
        lines.append(f'- {name}: {vals}')
    for name, par in result.get('equivalent_reading', {}).items():
        vals = ', '.join(f"{k} = {v:.5g} {par['unit'][k]}" for k, v in par.items() if k != 'unit')
        lines.append(f'- the same law while sliding, read as {name}: {vals}')
    eq = result.get('equivalence')
    if eq:
        verdict = ('tells them apart: the composite is named' if eq['told_apart'] else
                   'does not tell them apart: the elementary effects are named')
        rest = eq['heldout_fraction_at_rest']
        lines.append(f"- `{eq['composite']}` against `{eq['decomposition']}` (the same two "
                     f"force levels while sliding; they differ only at rest, "
                     f"{'?' if rest is None else f'{100 * rest:.1f} %'} of the held-out "
                     f"samples): held-out mean square error difference "
                     f"{eq['heldout_mse_difference']:.4g} against the margin {eq['margin']:.4g}; "
                     f'the record {verdict}')
    pl = result.get('play_or_loop')
    if pl and pl.get('plateau_fraction') is not None:
        growth = 'n/a' if pl['growth'] is None else f"{pl['growth']:.2f}"
        frac = 100 * pl['plateau_fraction']
        swap = ''
        if pl.get('replaced'):
            (was, now), = pl['replaced'].items()
            swap = f'; `{now}` named in place of `{was}`'
        lines.append(f"- after each reversal ({pl['half_cycles']} half-cycles, read on "
                     f"`{pl['read_on']}`): {pl['reading']} (median {frac:.0f} % of the "
                     f"transition near zero force; width growth with amplitude {growth})"
                     + swap)
    fl = result.get('friction_law')
    if fl:
        verdict = (f"`{fl['stribeck']}` named" if fl['stribeck_kept'] else
                   f"`{fl['coulomb']}` named: the Stribeck term explains too little beyond it")
        lines.append(f"- Stribeck against Coulomb friction: held-out mean square error above "
                     f"the noise {fl['excess_mse_stribeck']:.4g} against "
                     f"{fl['excess_mse_coulomb']:.4g} (needs {100 * fl['cut_needed']:.0f} % "
                     f"less and more than {fl['margin']:.4g}); {verdict}")
    mp = result['model_parameters']
    lines += [f"- model: m = {mp['m']:.5g} kg, c = {mp['c']:.5g} N s/m, k = {mp['k']:.5g} N/m"]
    sd = result['smoothing_differentiator']
    if 'cutoff_linear_fit_hz' in sd:
        linear = ('the same as' if sd['cutoff_hz'] == sd['cutoff_linear_fit_hz'] else
                  f"{sd['cutoff_linear_fit_hz']:.4g} Hz by")
        names = ', '.join(f'`{c}`' for c in sd['cutoff_candidates'])
        lines.append(f"- states: {sd['method']}, cut off at {sd['cutoff_hz']:.4g} Hz, where "
                     f"the best candidates ({names}) fit the held-out force best "
                     f"({linear} the linear fit's residual)")
    lines += ['', f"Alignment (nuisance, not an effect): {result['alignment_samples']:+.2f} "
              f"samples = {1e3 * result['alignment_s']:+.3f} ms.", '']
    dr = result.get('force_drift')
    if dr:
        verdict = ('a term of every model' if dr['decided'] else 'not a term (the record '
                   'shows none)')
        lines += [f"Force drift (nuisance, not an effect): {dr['F_d']:.5g} N over the record "
                  f"from its first sample, held-out information criterion "
                  f"{dr['ic_without']:.1f} without, {dr['ic_with']:.1f} with it on "
                  f"`{dr['read_on']}`: {verdict}.", '']
    lines += [
              '| held-out (later part) | force NRMSE |', '|---|---|',
              f"| before (linear m a + c v + k x) | {result['nrmse_before']:.4f} |",
              f"| after (updated model) | {result['nrmse_after']:.4f} |", '',
              f"gap closed: {result['gap_closed']:.3f}", '',
              '## Held-out evidence: hysteresis against a delayed law', '']
    for g, e in result['held_out_evidence'].items():
        lines.append(f"- best {g.replace('_', ' ')}: `{e['candidate']}`, held-out NRMSE "
                     f"{e['heldout_nrmse']:.4f}, information criterion "
                     f"{e['information_criterion']:.1f}")
    lines += ['', '## Every candidate (held-out NRMSE, information criterion)', '',
              '| candidate | held-out NRMSE | IC |', '|---|---|---|',
              f"| none (linear) | {result['nrmse_before']:.4f} | "
              f"{result['information_criterion_none']:.1f} |"]
    for k in sorted(result['candidates'], key=lambda k: result['information_criterion'][k]):
        lines.append(f"| {k} | {result['candidates'][k]:.4f} | "
                     f"{result['information_criterion'][k]:.1f} |")
    lines.append('')
    for key, title in (('surface', 'Restoring-force surface before and after'),
                       ('residuals', 'Force and residual')):
        if key in files:
            lines += [f'## {title}', '', f'![{title}]({files[key]})', '']
    return '\n'.join(lines)


# ---------------------------------------------------------------- real-data benchmark

#: Published EMPS parameters (Simulation_EMPS.m of the EMPS data set: IDIM-LS estimates).
EMPS_PUBLISHED = {'M': 95.1089, 'Fv': 203.5034, 'Fc': 20.3935, 'offset': -3.1648}
#: The real records of the benchmark: (label, kind, file name, NRMSE-after target).
REAL = [('EMPS', 'emps', 'DATA_EMPS.mat', 0.05),
        ('MR 10mm1Hz1A', 'mr-damper', '10mm1Hz1A.txt', 0.08),
        ('MR 25mm0x25Hz0x5A', 'mr-damper', '25mm0x25Hz0x5A.txt', 0.08),
        ('MR 2mm5Hz1A', 'mr-damper', '2mm5Hz1A.txt', 0.08)]


def find_file(data_dir, name):
    """Path of ``name`` anywhere under ``data_dir`` (None if absent)."""
    for root, _, files in os.walk(data_dir):
        if name in files:
            return os.path.join(root, name)
    return None


def emps_comparison(result):
    """Compare the EMPS fit with the published parameters (M, Fv, Fc, offset).

    Coulomb + offset maps directly; asymmetric friction F_p, F_n maps to
    ``Fc = (F_p + F_n) / 2`` and ``offset = (F_p - F_n) / 2`` (for a saturated
    ``tanh`` both laws are the same two levels).  The published model has no
    spring, so the constant part of our ``k x``, ``k mean(x)``, belongs to its
    offset: ``offset = F_0 + k mean(x)`` (the raw ``F_0`` is reported beside).  Nor a
    drift: where the record's force drifts (:func:`decide_drift`), ``F_0`` is the
    reading's zero at the first sample and its mean over the record, ``F_0 + F_d / 2``,
    is the published constant.
    """
    par = result['parameters']
    mp = result['model_parameters']
    got = {'M': mp['m'], 'Fv': mp['c']}
    spring_constant = mp['k'] * result['displacement_mean_m']
    drift = result.get('force_drift') or {}
    drift_mean = 0.5 * drift['F_d'] if drift.get('decided') else 0.0
    if 'coulomb_friction' in par:
        got['Fc'] = par['coulomb_friction']['F_c']
        got['offset'] = par.get('force_offset', {}).get('F_0', 0.0)
    elif 'asymmetric_friction' in par:
        fp, fn = par['asymmetric_friction']['F_p'], par['asymmetric_friction']['F_n']
        got['Fc'] = 0.5 * (fp + fn)
        got['offset'] = 0.5 * (fp - fn) + par.get('force_offset', {}).get('F_0', 0.0)
    raw_offset = got.get('offset')
    if 'offset' in got:
        got['offset'] += spring_constant + drift_mean
    errors = {k: abs(got[k] - v) / abs(v) for k, v in EMPS_PUBLISHED.items() if k in got}
    return {'published': EMPS_PUBLISHED, 'fitted': got, 'relative_errors': errors,
            'offset_without_spring_constant': raw_offset,
            'spring_constant_force_N': spring_constant,
            'drift_mean_force_N': drift_mean,
            'within_10_percent': bool(len(errors) == 4 and max(errors.values()) <= 0.10)}


def run_real(data_dir, out_dir=None, progress=None, count=None):
    """Run every record of :data:`REAL` found under ``data_dir``; return the summary.

    ``progress(text)`` gets the steps, ``count(done, total)`` the records done.
    """
    say = progress or (lambda msg: None)
    rows = []
    for label, kind, name, target in REAL:
        if count:
            count(len(rows), len(REAL))
        path = find_file(data_dir, name)
        if path is None:
            say(f'{label}: {name} not found under {data_dir}; skipped')
            rows.append({'record': label, 'file': name, 'skipped': 'file not found'})
            continue
        t0 = time.perf_counter()
        say(f'{label}: {path}')
        sub = os.path.join(out_dir, name.split('.')[0]) if out_dir else None
        res = run(validate(convert(kind, path)), out_dir=sub, progress=say, source=name)
        row = {'record': label, 'file': name, 'effect': res['effect'],
               'parameters': res['parameters'], 'model_parameters': res['model_parameters'],
               'nrmse_before': res['nrmse_before'], 'nrmse_after': res['nrmse_after'],
               'gap_closed': res['gap_closed'], 'alignment_s': res['alignment_s'],
               'alignment_samples': res['alignment_samples'],
               'held_out_evidence': res['held_out_evidence'],
               'candidates_best5': dict(sorted(res['candidates'].items(),
                                               key=lambda kv: res['information_criterion'][
                                                   kv[0]])[:5]),
               'nrmse_target': target, 'nrmse_target_met': res['nrmse_after'] <= target,
               'seconds': time.perf_counter() - t0}
        if kind == 'emps':
            row['published_comparison'] = emps_comparison(res)
            row['effect_target_met'] = (
                any(k in res['parameters'] for k in ('coulomb_friction', 'asymmetric_friction'))
                and 'force_offset' in res['parameters'])
        rows.append(row)
    if count:
        count(len(rows), len(REAL))
    return {'records': rows,
            'sources': {
                'EMPS': 'github.com/forgi86/sysid-neural-continuous, examples/EMPS/data '
                        '(Apache-2.0); EMPS benchmark, A. Janot, M. Gautier, M. Brunot',
                'MR damper': 'github.com/DanielMaurelE/vRTHS_AMBC_MRdamper, Cap7_ModeloMR/'
                             'BoucWen Ajuste 1/Preprocesamiento-sinusoidales/Preprocesados '
                             '(MIT)'}}
