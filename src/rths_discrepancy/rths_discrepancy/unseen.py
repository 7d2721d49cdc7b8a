"""Unseen-data battery: records of the kind labs bring, from a third, independent simulator.

The workflow was developed on :mod:`.selftest` and judged on :mod:`.heldout`; the
records here come from code written separately again, with its own conventions,
so that what passes here is the method and not its tuning:

* physics: the specimen's motion is *analytic* (a displacement-controlled test:
  sums of sines, chirps, stepped sines, whose velocity and acceleration are
  differentiated by hand, never numerically) or *integrated* by SciPy's DOP853
  (rtol 1e-9) under an analytic shaker force; history elements (play, Bouc-Wen
  of other shapes than the library's, a friction slider behind a clearance) are
  stepped on a 16x finer grid by their own loops below;
* rates non-round (250-5000 Hz, e.g. 610.35 Hz), 2500-16000 samples, excitations
  multisine (periodic, 2-8 periods), swept sine, stepped sine, random phase
  broadband, noise 0.1-3 % of the force's spread (displacement a fifth of it,
  at least 0.05 %), channels in volts, mm, kN or integer counts with offsets, a
  slow drift on some force channels;
* effects (the names the literature gives them): ``cubic_stiffness``
  (hardening and softening Duffing), ``backlash`` (a spring behind a clearance,
  the F-16 joint; a friction damper with play), ``coulomb_friction``,
  ``stribeck``, ``hysteresis`` (Bouc-Wen), ``quadratic_damping`` (``c2 v |v|``)
  in restoring-force records; ``cubic_stiffness``, ``saturation`` (an output
  that clips) in input-output records; linear controls (answer ``none``).

Each case's parameters are drawn from a seed given to :func:`battery`; the bench
(``rths bench discrepancy-unseen``) states the seed it used, fixed after the
method was settled.  Judgement per case (:func:`judge`): the expected name among
the names given, at most one extra name, and for a named effect the gap closed at
least half of what the true model closes (the true model: the noise-free
generator output in the record's units, i.e. its error is the noise).  The errors
are those of the measure the workflow states: free-run simulation, or, on an
input-output record no model simulates free-run (a near-chaotic Duffing), simulation
re-initialised from the measured output every few periods (``error_measure``).
"""

import math
import time

import numpy as np
from scipy import integrate

from rths_discrepancy import iodisc, restoring

SUB = 16
#: The rates a case is drawn from (Hz): odd, non-round values as well as round ones.
RATES = (250.0, 409.6, 610.35, 1000.0, 1234.5, 2048.0, 3300.0, 5000.0)
#: The restoring-force effects of the battery and the name each must get.
RF_EFFECTS = {
    'linear': None, 'cubic_hardening': 'cubic_stiffness', 'cubic_softening': 'cubic_stiffness',
    'clearance_spring': 'backlash', 'friction_with_play': 'backlash',
    'coulomb': 'coulomb_friction', 'stribeck': 'stribeck', 'bouc_wen': 'hysteresis',
    'quadratic_damping': 'quadratic_damping'}
IO_EFFECTS = {'linear': None, 'duffing': 'cubic_stiffness', 'output_clipping': 'saturation'}
EXCITATIONS = ('multisine', 'swept_sine', 'stepped_sine', 'random')
UNITS = {  # (displacement gain per m, unit), (force gain per N, unit)
    'SI': ((1.0, 'm'), (1.0, 'N')),
    'mm_kN': ((1e3, 'millimetre'), (1e-3, 'kN')),
    'volts': ((250.0, 'V'), (2e-3, 'V')),
    'counts': ((2e6, 'counts'), (50.0, 'counts')),
}


# ---------------------------------------------------------------- motion (analytic)

class Motion:
    """x(t), v(t), a(t) as sums of sinusoids with per-component phase laws."""

    def __init__(self, kind, fs, n, band, rng):
        self.kind, self.fs, self.n = kind, fs, n
        t_end = n / fs
        lo, hi = band
        if kind == 'multisine':
            periods = int(rng.choice([2, 3, 4, 8]))
            p = n // periods
            self.period_samples = p
            f0 = fs / p
            ks = np.arange(max(1, math.ceil(lo / f0)), max(2, math.floor(hi / f0)) + 1)
            self.comps = [(f0 * k, 1.0 / max(f0 * k, lo) ** 1.0, rng.uniform(0, 2 * np.pi))
                          for k in ks]
        elif kind == 'random':
            m = 60
            freqs = np.sort(rng.uniform(lo, hi, m))
            self.comps = [(f, 1.0 / f, rng.uniform(0, 2 * np.pi)) for f in freqs]
        elif kind == 'swept_sine':
            self.f_a, self.f_b = lo, hi
            self.t_end = t_end
        elif kind == 'stepped_sine':
            steps = int(rng.integers(3, 6))
            self.steps = np.geomspace(lo, hi, steps)
            self.t_end = t_end
        else:
            raise ValueError(kind)

    def x_at(self, t):
        """Displacement at one time ``t`` (a sum of sinusoids; for an ODE's right-hand side).

        The same sum as :meth:`states` in one vector operation: the shaker tests call it
        at every stage of every integration step, where a loop over the components made
        a 4000-sample record take minutes.
        """
        if not hasattr(self, '_vec'):
            f, amp, ph = (np.array(v) for v in zip(*self.comps, strict=True))
            self._vec = (2 * np.pi * f, amp, ph)
        w, amp, ph = self._vec
        return float(np.dot(amp, np.sin(w * t + ph)))

    def states(self, t):
        """Displacement, velocity, acceleration at times ``t`` (not yet scaled)."""
        if self.kind in ('multisine', 'random'):
            x = np.zeros_like(t)
            v = np.zeros_like(t)
            a = np.zeros_like(t)
            for f, amp, ph in self.comps:
                w = 2 * np.pi * f
                s, c = np.sin(w * t + ph), np.cos(w * t + ph)
                x += amp * s
                v += amp * w * c
                a -= amp * w * w * s
            return x, v, a
        if self.kind == 'swept_sine':
            # log sweep f(t) = f_a r^(t/T), phase = 2 pi f_a T (r^(t/T) - 1) / ln r
            r, big_t = self.f_b / self.f_a, self.t_end
            lr = math.log(r)
            ph = 2 * np.pi * self.f_a * big_t * (np.power(r, t / big_t) - 1) / lr
            w = 2 * np.pi * self.f_a * np.power(r, t / big_t)
            dw = w * lr / big_t
            amp = 1.0 / (w / (2 * np.pi))     # constant velocity amplitude
            damp = -amp * dw / w
            x = amp * np.sin(ph)
            v = damp * np.sin(ph) + amp * w * np.cos(ph)
            ddamp = -(damp * dw / w) + amp * (dw / w) ** 2 - amp * (dw * lr / big_t) / w
            a = (ddamp * np.sin(ph) + 2 * damp * w * np.cos(ph) + amp * dw * np.cos(ph)
                 - amp * w * w * np.sin(ph))
            return x, v, a
        # stepped sine: equal-length dwell per frequency, amplitude from 1/f, a smooth
        # raised-cosine envelope (analytic derivatives) in each dwell
        k = len(self.steps)
        dwell = self.t_end / k
        x = np.zeros_like(t)
        v = np.zeros_like(t)
        a = np.zeros_like(t)
        for i, f in enumerate(self.steps):
            tt = t - i * dwell
            inside = (tt >= 0) & (tt < dwell)
            w, wn = 2 * np.pi * f, 2 * np.pi / dwell
            e = 0.5 * (1 - np.cos(wn * tt))
            de = 0.5 * wn * np.sin(wn * tt)
            dde = 0.5 * wn * wn * np.cos(wn * tt)
            amp = 1.0 / f
            s, c = np.sin(w * tt), np.cos(w * tt)
            x += inside * amp * e * s
            v += inside * amp * (de * s + e * w * c)
            a += inside * amp * (dde * s + 2 * de * w * c - e * w * w * s)
        return x, v, a


# ---------------------------------------------------------------- history elements

def _play_fine(x, b):
    z = np.empty_like(x)
    zi = x[0]
    for i, xi in enumerate(x):
        if xi - zi > b:
            zi = xi - b
        elif zi - xi > b:
            zi = xi + b
        z[i] = zi
    return z


def _bouc_wen_fine(x, x_y, n_exp, beta, gamma):
    """Bouc-Wen z (dimensionless, |z| <= (beta+gamma)^(-1/n)) by trapezoidal steps in x."""
    z = np.zeros_like(x)
    zi = 0.0
    for i in range(1, x.size):
        dx = (x[i] - x[i - 1]) / x_y

        def rate(zz, dx=dx):
            return 1.0 - abs(zz) ** n_exp * (beta + gamma * np.sign(dx * zz))
        k1 = rate(zi)
        k2 = rate(zi + dx * k1)
        zi = zi + 0.5 * dx * (k1 + k2)
        z[i] = zi
    return z


# ---------------------------------------------------------------- cases

def _draw_rf(rng, effect, idx):
    fs = float(rng.choice(RATES))
    n = int(rng.choice([2500, 4000, 6000, 10000, 16000]))
    exc = EXCITATIONS[idx % len(EXCITATIONS)] if effect != 'linear' else str(
        rng.choice(EXCITATIONS))
    hi = min(rng.uniform(0.02, 0.12) * fs, 400.0)
    lo = max(hi / rng.uniform(8, 40), 8.0 * fs / n)
    units = str(rng.choice(list(UNITS)))
    return {'scenario': 'restoring-force', 'effect': effect, 'fs': fs, 'n': n,
            'excitation': exc, 'band_hz': [float(lo), float(hi)], 'units': units,
            'noise': float(np.exp(rng.uniform(np.log(1e-3), np.log(3e-2)))),
            'offset': bool(rng.random() < 0.5), 'drift': bool(rng.random() < 0.25),
            'mass_kg': float(np.exp(rng.uniform(np.log(0.5), np.log(200.0)))),
            'fn_over_band': float(rng.uniform(0.3, 3.0)), 'zeta': float(rng.uniform(0.01, 0.1)),
            'size': float(rng.uniform(0.25, 0.6)), 'shape': float(rng.uniform(0.0, 1.0)),
            'xpk_m': float(np.exp(rng.uniform(np.log(1e-4), np.log(2e-2)))),
            'seed': int(rng.integers(2 ** 31))}


def restoring_case(case):
    """Generate one restoring-force record; return (data for restoring.run, clean force)."""
    rng = np.random.default_rng(case['seed'])
    fs, n = case['fs'], case['n']
    mot = Motion(case['excitation'], fs, n, case['band_hz'], rng)
    t = np.arange(n) / fs
    tf = np.arange(n * SUB) / (fs * SUB)
    x, v, a = mot.states(t)
    xf = mot.states(tf)[0]
    g = case['xpk_m'] / np.max(np.abs(x))
    x, v, a, xf = x * g, v * g, a * g, xf * g
    m = case['mass_kg']
    fn = case['fn_over_band'] * np.sqrt(case['band_hz'][0] * case['band_hz'][1])
    k = m * (2 * np.pi * fn) ** 2
    c = 2 * case['zeta'] * math.sqrt(k * m)
    f_lin = m * a + c * v + k * x
    ref = float(np.std(f_lin))          # the nonlinear force is sized against it
    size, sh = case['size'], case['shape']
    xpk, vs = float(np.max(np.abs(x))), float(np.std(v))
    eff = case['effect']
    if eff == 'linear':
        f_nl = np.zeros(n)
    elif eff in ('cubic_hardening', 'cubic_softening'):
        sign = 1.0 if eff == 'cubic_hardening' else -1.0
        k3 = sign * (0.3 + 0.4 * sh) * k / xpk ** 2      # k3 xpk^2 = 30-70 % of k
        f_nl = k3 * x ** 3
    elif eff == 'clearance_spring':
        b = (0.1 + 0.3 * sh) * xpk
        f_nl = (1.0 + 2.0 * sh) * k * np.sign(x) * np.maximum(np.abs(x) - b, 0.0)
    elif eff == 'friction_with_play':
        b = (0.05 + 0.15 * sh) * xpk
        z = _play_fine(xf, b)
        dz = np.gradient(z) * fs * SUB
        fc = size * ref
        f_nl = (fc * np.tanh(dz / (1e-3 * np.max(np.abs(dz)))))[::SUB]
    elif eff == 'coulomb':
        f_nl = size * ref * np.tanh(v / (2e-3 * vs))
    elif eff == 'stribeck':
        fc = 0.5 * size * ref
        v_s = (0.1 + 0.3 * sh) * vs
        f_nl = (fc + 1.5 * fc * np.exp(-(v / v_s) ** 2)) * np.tanh(v / (2e-3 * vs))
    elif eff == 'bouc_wen':
        n_exp = 1.0 + 1.5 * sh
        beta, gamma = 0.3 + 0.4 * sh, 0.7 - 0.4 * sh
        zf = _bouc_wen_fine(xf, (0.05 + 0.25 * sh) * xpk, n_exp, beta, gamma)
        f_nl = size * ref * zf[::SUB] * (beta + gamma) ** (1 / n_exp)
    elif eff == 'quadratic_damping':
        c2 = size * ref / (np.std(v * np.abs(v)))
        f_nl = c2 * v * np.abs(v)
    else:
        raise ValueError(eff)
    f = f_lin + f_nl
    (gx, ux), (gf, uf) = UNITS[case['units']]
    x_rec = gx * x
    f_rec = gf * f
    if case['offset']:
        x_rec = x_rec + rng.uniform(-1, 1) * 2 * np.std(x_rec)
        f_rec = f_rec + rng.uniform(-1, 1) * 2 * np.std(f_rec)
    if case['drift']:
        f_rec = f_rec + 0.02 * np.std(f_rec) * t / t[-1]
    clean = f_rec.copy()
    noise = case['noise']
    f_rec = f_rec + noise * np.std(f) * gf * rng.standard_normal(n)
    x_rec = x_rec + max(noise / 5, 5e-4) * np.std(x_rec) * rng.standard_normal(n)
    if case['units'] == 'counts':
        x_rec, f_rec, clean = np.round(x_rec), np.round(f_rec), clean
    data = {'time_s': t, 'displacement_m': x_rec, 'force_N': f_rec}
    return data, clean


def _draw_io(rng, effect, idx):
    fs = float(rng.choice(RATES))
    n = int(rng.choice([4000, 6000, 10000]))
    fn = float(rng.uniform(0.01, 0.05) * fs)
    units = str(rng.choice(list(UNITS)))
    return {'scenario': 'io', 'effect': effect, 'fs': fs, 'n': n, 'fn_hz': fn,
            'excitation': 'random' if idx % 2 == 0 else 'multisine',
            'zeta': float(rng.uniform(0.02, 0.08)), 'units': units,
            'noise': float(np.exp(rng.uniform(np.log(1e-3), np.log(2e-2)))),
            'size': float(rng.uniform(0.3, 0.8)), 'offset': bool(rng.random() < 0.5),
            'seed': int(rng.integers(2 ** 31))}


def io_case(case):
    """Generate one input-output record (shaker force to displacement) and its clean output."""
    rng = np.random.default_rng(case['seed'])
    fs, n = case['fs'], case['n']
    band = (0.2 * case['fn_hz'], 3.0 * case['fn_hz'])
    mot = Motion(case['excitation'], fs, n, band, rng)
    wn = 2 * np.pi * case['fn_hz']
    zeta = case['zeta']
    eff = case['effect']
    t = np.arange(n) / fs
    u_raw = mot.states(t)[0]
    scale_u = 1.0 / np.std(u_raw)
    k3 = 0.0
    if eff == 'duffing':
        # the linear response's spread sets the cubic: k3 x_rms^2 = size x k (hardening)
        x_lin = _integrate(lambda tt: scale_u * mot.x_at(tt), wn, zeta, 0.0, t)
        k3 = 3.0 * case['size'] * wn ** 2 / np.std(x_lin) ** 2
    x = _integrate(lambda tt: scale_u * mot.x_at(tt), wn, zeta, k3, t)
    if eff == 'output_clipping':
        lim = (1.0 - 0.5 * case['size']) * np.max(x)
        x = np.minimum(x, lim)
    u = u_raw * scale_u
    (gx, _), (gf, _) = UNITS[case['units']]
    y = gx * x
    u = gf * 1e3 * u
    if case['offset']:
        y = y + rng.uniform(-1, 1) * 2 * np.std(y)
        u = u + rng.uniform(-1, 1) * 0.5 * np.std(u)
    clean = y.copy()
    y = y + case['noise'] * np.std(y) * rng.standard_normal(n)
    if case['units'] == 'counts':
        y = np.round(y)
    return {'u': u, 'y': np.column_stack([y]), 'fs': fs, 'source': case['name'],
            'outputs': ['y'], 'input': 'u'}, clean


def _integrate(force, wn, zeta, k3, t):
    """Return x of x'' + 2 zeta wn x' + wn^2 x + k3 x^3 = f(t), by DOP853 (rtol 1e-9)."""
    def rhs(tt, s):
        return [s[1], force(tt) - 2 * zeta * wn * s[1] - wn * wn * s[0] - k3 * s[0] ** 3]
    sol = integrate.solve_ivp(rhs, (t[0], t[-1]), [0.0, 0.0], method='DOP853', t_eval=t,
                              rtol=1e-9, atol=1e-12, max_step=t[1] - t[0])
    return sol.y[0]


def battery(seed, per_effect=2, io_per_effect=1):
    """Return the cases (dicts of parameters) drawn from ``seed``."""
    rng = np.random.default_rng(seed)
    cases = []
    for eff in RF_EFFECTS:
        for i in range(per_effect + (1 if eff == 'linear' else 0)):
            c = _draw_rf(rng, eff, i)
            c['name'] = f'rf_{eff}_{i}'
            cases.append(c)
    for eff in IO_EFFECTS:
        for i in range(io_per_effect):
            c = _draw_io(rng, eff, i)
            c['name'] = f'io_{eff}_{i}'
            cases.append(c)
    return cases


def _names(effect):
    return [] if effect in ('none', '') else effect.split('+')


def allowed(case):
    """Return the expected name and the names true of a case (``force_offset`` with an offset).

    A displacement or force channel with an offset (a transducer's zero, volts about a
    bias) makes a constant force term of the record: the library names it
    ``force_offset``, which is then no extra name.
    """
    want = (RF_EFFECTS if case['scenario'] == 'restoring-force' else IO_EFFECTS)[case['effect']]
    true = {want} if want else set()
    if case['scenario'] == 'restoring-force' and case.get('offset'):
        true.add('force_offset')
    return want, true


def judge(case, names, gap_ratio):
    """Whether a case passes: expected name given, <= 1 extra name, gap >= half the true one.

    A linear control passes with no name but an offset the record holds.
    """
    want, true = allowed(case)
    if want is None:
        return set(names) <= true
    if 'unexplained' in names or want not in names:
        return False
    return len(set(names) - true) <= 1 and gap_ratio is not None and gap_ratio >= 0.5


def _test_mask(n):
    m = np.zeros(n, bool)
    m[int(restoring.TRAIN_FRACTION * n):int(0.98 * n)] = True
    return m


def run_case(case):
    """Run the workflow on one case; return the row (names, errors, gap ratio, seconds)."""
    t0 = time.perf_counter()
    measure = 'free-run simulation'
    if case['scenario'] == 'restoring-force':
        data, clean = restoring_case(case)
        data = restoring.validate(data, source=case['name'])
        cut, _ = restoring.whole_periods(data)
        res = restoring.run(data, plots=False)
        nc = cut['force_N'].size
        te = _test_mask(nc)
        f = cut['force_N']
        true = float(np.sqrt(np.mean((f[te] - clean[:nc][te]) ** 2)) / np.std(f[te]))
        before, after = res['nrmse_before'], res['nrmse_after']
        if case['offset']:      # the gap of the effect: from the nominal with its offset
            before = min(before, res['candidates']['force_offset'])
    else:
        rec, clean = io_case(case)
        res = iodisc.run([rec], plots=False)
        p = res['per_output']['y']
        # in the measure the run states (free run, or short-horizon simulation where no
        # model simulates the record): the true model's error is the noise in either
        before, after = p['nrmse_baseline'], p['nrmse_after']
        measure = p['error_measure']['kind']
        if 'horizon_samples' in p['error_measure']:
            measure += f" every {p['error_measure']['horizon_samples']} samples"
        k = int(iodisc.TRAIN_FRACTION * rec['u'].size)
        y = rec['y'][k:, 0]
        true = float(np.sqrt(np.mean((y - clean[k:]) ** 2)) / np.std(y))
    names = _names(res['effect'])
    closable = before ** 2 - true ** 2
    ratio = float((before ** 2 - after ** 2) / closable) if closable > 0 else None
    return {'case': case['name'], 'scenario': case['scenario'], 'generator_effect':
            case['effect'], 'expected': (RF_EFFECTS if case['scenario'] == 'restoring-force'
                                         else IO_EFFECTS)[case['effect']] or 'none',
            'named': res['effect'], 'nrmse_before': before, 'nrmse_after': after,
            'nrmse_true_model': true, 'gap_closed_vs_true': ratio,
            'error_measure': measure,
            'passed': judge(case, names, ratio), 'seconds': time.perf_counter() - t0,
            'parameters': case}


def summarise(rows):
    """Per expected effect: cases, passed, names given."""
    table = {}
    for r in rows:
        e = table.setdefault(r['generator_effect'] if r['scenario'] == 'restoring-force'
                             else 'io_' + r['generator_effect'],
                             {'expected': r['expected'], 'cases': 0, 'passed': 0, 'named': []})
        e['cases'] += 1
        e['passed'] += int(r['passed'])
        e['named'].append(r['named'])
    return table
