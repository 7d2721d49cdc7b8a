"""The discrepancy workflow: residual, localisation, candidate effects, naming, proof.

1. Re-simulate the nominal model with the measured input; the residual is
   ``r = y_meas - y_nom`` (specimen output: ``rel_disp`` x_d2s of eq. 46-47;
   actuator output: ``measured``).
2. Localise ``r`` in time, frequency and state (:mod:`.localize`).
3. Fit each candidate of :mod:`.effects` (and pairs) on the training blocks
   and score it on the held-out blocks.  A loop effect with term ``q`` is
   predicted with the measured (smoothed) states as
   ``y = y_nom + G[s q(x, xd, xdd, u)]`` (``G`` the nominal linear filter,
   eq. 47 for the specimen with ``s = +1``; the actuator ``y = G (u - q)``,
   ``s = -1``), which is exact when the states are exact and linear in the
   parameters of the linear effects (variable projection: linear parameters
   by least squares, non-linear ones by a 1-D/2-D search).
4. Decision on the held-out blocks.  Score ``S`` = held-out mean square
   error of the output divided by its white-noise variance ``sigma^2``
   (:func:`.signals.noise_variance`), plus, for the specimen, the same for the
   restoring-force residual ``F_meas - (c_d xd + k_d x)`` (eq. 45; it separates
   stiffness from mass errors, which the displacement alone hardly does).  The
   floor of ``S`` is the number of channels.  No effect is named unless its
   gain ``S_0 - S`` exceeds ``MIN_GAIN`` (noise variances) and ``MIN_REL_GAIN``
   of the reducible gap ``S_0 - floor``; all parameters of a pair are refitted
   jointly and the pair replaces the best single only if it removes a further
   ``PAIR_REL_GAIN`` of the gap and ``PAIR_REMAINING`` of what the single
   left; if the winner closes less than ``NAME_CLOSURE`` of the output's
   reducible gap (all scored samples) and leaves more than ``UNEXPLAINED_MIN``
   noise variances unexplained, the answer is ``unexplained``.
   Amplitude coverage: training and held-out blocks alternate every ~0.5 s,
   so both see the rare large-amplitude events; an unequal residual excess of
   the two parts is reported as a coverage warning.  The held-out error also
   enters a BIC-style criterion ``IC = N ln S + p ln N`` (N held-out samples,
   p fitted parameters; the nominal model has p = 0): an effect is named only
   if it lowers the IC below the nominal model's, and a pair replaces the best
   single only if it lowers the IC further (so an extra parameter must pay for
   itself on unseen data); every candidate's IC is reported with the evidence.
   Distinct from its rivals: a name is given only if the winner's IC is
   ``DISTINCT_IC`` below that of the best candidate sharing none of its
   effects (the rival).  Near the detection limit two different effects can
   explain a small residual equally well (a 0.08 N Coulomb friction and a
   viscous error); the record then shows that something is there but not what:
   the answer is ``unexplained``, with the tie as the reason, never the rival's
   name.
5. The winner is added to the model and the model is re-simulated *without*
   measured states (output error); ``gap_closed = (NRMSE_before^2 -
   NRMSE_after^2) / (NRMSE_before^2 - NRMSE_noise^2)`` on the held-out blocks.
"""

import itertools
import math

import numpy as np
from scipy import optimize
from scipy.signal import lfilter

from rths_discrepancy import effects as fx
from rths_discrepancy import io as dio
from rths_discrepancy import localize, models, report
from rths_discrepancy import signals as sg

#: Held-out gain needed to name anything, in units of the noise variance.
MIN_GAIN = 0.2
#: ... and as a fraction of the reducible gap S_0 - sigma^2.
MIN_REL_GAIN = 0.2
#: Extra fraction of the gap a pair must close beyond its best single member.
PAIR_REL_GAIN = 0.005
#: ... and the fraction of what the single left that the pair must remove.
PAIR_REMAINING = 0.75
#: Fraction of the gap the winner must close to be named (else 'unexplained').
NAME_CLOSURE = 0.95
#: ... and the output's remaining excess must exceed this many noise variances.
UNEXPLAINED_MIN = 0.5
#: IC margin by which the winner must beat its best rival that shares none of its effects
#: (6: "strong" evidence on the scale of Kass and Raftery, 1995); below it, 'unexplained'.
DISTINCT_IC = 6.0
#: Number of best single effects that are combined with every other effect.
PAIR_TOP = 3
#: ... and every pair is fitted when the best fit so far leaves more than this many noise
#: variances above the floor.
PAIR_WIDEN = 1.0
#: Floor of the noise estimates relative to the signal's standard deviation: a noise-free
#: record (a simulated plant without sensor noise) whose model agrees to round-off has
#: nothing to explain, so the answer is 'none', not an effect fitted to round-off.
ROUND_OFF = 1e-9
#: Resolution of a model of the output, relative to its standard deviation: an identified
#: plant (an ARX model of rths identify) reproduces a noise-free record to a few 1e-4, so
#: the output's noise floor is never taken below this and a disagreement within it (a
#: nominal run of a noise-free simulated lab against its identified plant) is 'none'.
#: Real sensors are noisier than this; it only applies to noise-free simulations.
MODEL_RESOLUTION = 1e-3
#: Half-width of the model-measurement alignment band [samples]: how far apart the DAQ
#: conventions of two labs can put the same sample (input held or interpolated over a step:
#: 0.5; output read at the start or the end of the step, or one more step of converter
#: delay: 1; one of each: 1.5).  The alignment is a nuisance parameter of every fit; only a
#: delay outside this band (a real delay of 2 samples or more) is a ``time_delay``.
ALIGN_SAMPLES = 1.5

INPUT = {'specimen': 'base_accel', 'actuator': 'command'}
OUTPUT = {'specimen': 'rel_disp', 'actuator': 'measured'}
_OUTPUT_OPS = {'specimen': ('time_delay', 'sensor_bias', 'force_offset'),
               'actuator': ('time_delay', 'sensor_bias', 'backlash', 'velocity_saturation')}


class Context:
    """Everything the candidate fits share: signals, nominal response, masks, noise."""

    def __init__(self, scenario, data, model):
        self.scenario = scenario
        self.model = model
        self.fs = dio.sample_rate(data)
        self.u = data[INPUT[scenario]]
        self.y = data[OUTPUT[scenario]]
        self.n = self.y.size
        self.lib = fx.LIBRARY[scenario]
        ops = _OUTPUT_OPS[scenario]
        self.out_eff = {k: v for k, v in model.effects.items() if k in ops and k != 'time_delay'}
        self.base_delay = float(model.effects.get('time_delay', 0.0))
        core = models.with_effects(model, {})
        core.effects = {k: v for k, v in model.effects.items() if k not in ops}
        self.y_core = core.simulate(self.u, self.fs)[OUTPUT[scenario]]
        self.align_max = ALIGN_SAMPLES / self.fs
        self.train, self.test = sg.block_masks(
            self.n, max(10, 2 * int(round(self.n / self.fs))))
        self._shifted = {}
        self.nonlinear_out = scenario == 'actuator' and any(
            k in self.out_eff for k in ('backlash', 'velocity_saturation'))
        self.y_nom_raw = self.output({}, 0.0)
        self.alignment = self.fit_alignment()
        self.y_nom = self.output({}, self.alignment)
        self.b, self.a = model.linear_filter(self.fs)
        st = sg.states(self.y, self.fs, u=self.u)
        if scenario == 'actuator':
            # the friction load's sign switches with the table's velocity within a few
            # samples at a reversal: its velocity is band-limited as widely as the record's
            # noise allows (signals.sign_band; at the input's band a hidden Coulomb load was
            # fitted 5 % small and a play was named beside it)
            fc_sign = sg.sign_band(self.fs, st['fc'],
                                   sg.noise_variance(self.y - self.y_nom, self.fs), fx.V_EPS)
            st['v_sign'] = sg.states(self.y, self.fs, fc=fc_sign)['v']
            # the load held over sample k is its value mid-sample (t_k - T/2), as simulated
            st = {k: (fx.delay(v, 0.5 / self.fs, self.fs) if k != 'fc' else v)
                  for k, v in st.items()}
        st['u'] = fx.delay(self.u, self.alignment, self.fs)  # in the measurement's frame
        self.states = st
        self.sign = 1.0 if scenario == 'specimen' else -1.0
        self.sigma2 = max(sg.noise_variance(self.y - self.y_nom, self.fs),
                          (MODEL_RESOLUTION * float(np.std(self.y))) ** 2)
        self.scales = {'y_rms': float(np.std(self.y)), 'v_rms': float(np.std(st['v'])),
                       'v_max': float(np.max(np.abs(st['v'])))}
        self._cols = {}
        self.force_rows = scenario == 'specimen' and 'force' in data
        if self.force_rows:
            force_nl = np.vectorize(fx.specimen_force(
                {k: v for k, v in model.effects.items() if k not in ops}, model))
            self.e_r = data['force'] - (model.c_d * st['v'] + model.k_d * st['x']
                                        + force_nl(st['x'], st['v'])
                                        - model.effects.get('force_offset', 0.0))
            self.sigma2_f = max(sg.noise_variance(self.e_r, self.fs),
                                (ROUND_OFF * float(np.std(data['force']))) ** 2)
            self.force_nuisance = self._force_lag_columns(data, st['fc'])

    def _force_lag_columns(self, data, fc):
        """Columns of a small lag between the force channel and the kinematic channels.

        The force the damper exerts is derived from two channels (the load cells and the
        frame's accelerometer) that may sit behind different anti-alias filters than the
        displacement sensor.  A lag ``tau`` of one against the others adds about
        ``tau d/dt`` of that channel to the force residual; both derivatives are free
        nuisance columns of the force rows (zero in the displacement rows), fitted with
        every candidate, so such a lag is not read as a damping or stiffness error.
        """
        cols = []
        for key in ('force', 'base_accel'):
            d = sg.lowpass(np.gradient(np.asarray(data[key], float), 1.0 / self.fs),
                           self.fs, fc)
            cols.append(d / max(float(np.std(d)), 1e-300))
        return np.column_stack(cols)

    def column(self, name):
        """Return the filtered regressor ``G[s phi]`` of a linear loop effect (cached)."""
        if name not in self._cols:
            phi = fx.loop_regressor(self.scenario, name, self.states, self.model)
            self._cols[name] = lfilter(self.b, self.a, self.sign * phi)
        return self._cols[name]

    def core_shifted(self, tau):
        """Nominal core response delayed by ``tau`` [s] (cached; band-limited delay)."""
        key = round(float(tau) * self.fs, 6)
        if key not in self._shifted:
            if len(self._shifted) > 64:
                self._shifted.clear()
            self._shifted[key] = fx.delay(self.y_core, key / self.fs, self.fs)
        return self._shifted[key]

    def output(self, params, align):
        """Model output with the output operators of ``params`` and the alignment ``align``.

        The loop effects' contributions are added by :meth:`predict`; here only the
        nominal core, delayed by the alignment (or by the ``time_delay`` of ``params``,
        which then replaces it), and the output operators.
        """
        tau = self.base_delay + float(params.get('time_delay', align))
        outs = {**self.out_eff, **{k: v for k, v in params.items()
                                   if self.lib[k].kind == 'output' and k != 'time_delay'}}
        return fx.apply_output_ops(self.scenario, self.core_shifted(tau), outs, self.fs)

    def fit_alignment(self):
        """Alignment [s] of the nominal model to the measurement, within +-``align_max``.

        Least squares on the training blocks over a 0.25-sample grid, refined by a
        bounded scalar search (the model-measurement lag of the DAQ conventions).
        """
        h = self.align_max
        grid = np.linspace(-h, h, int(round(8 * ALIGN_SAMPLES)) + 1)

        def cost(a):
            return self.mse(self.output({}, a), self.train)

        costs = [cost(a) for a in grid]
        i = int(np.argmin(costs))
        lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
        res = optimize.minimize_scalar(cost, bounds=(lo, hi), method='bounded',
                                       options={'xatol': 1e-3 / self.fs, 'maxiter': 25})
        return float(res.x) if res.fun <= costs[i] else float(grid[i])

    def predict(self, params, align=None):
        """Fast prediction of the model plus the effects ``params`` ({name: value})."""
        align = self.alignment if align is None else align
        y = self.core_shifted(self.base_delay + float(params.get('time_delay', align))).copy()
        for name, val in params.items():
            e = self.lib[name]
            if e.kind != 'loop':
                continue
            if e.linear:
                y += val * self.column(name)
            else:
                q = fx.loop_term_nonlinear(name, val, self.states, self.model)
                y += lfilter(self.b, self.a, self.sign * q)
        outs = {**self.out_eff, **{k: v for k, v in params.items()
                                   if self.lib[k].kind == 'output' and k != 'time_delay'}}
        return fx.apply_output_ops(self.scenario, y, outs, self.fs)

    def mse(self, pred, mask):
        """Mean square error of the output prediction ``pred`` on ``mask``."""
        return float(np.mean((self.y[mask] - pred[mask]) ** 2))

    def psi(self, name, params):
        """Restoring-force term [N] of effect ``name`` at the measured states (eq. 45).

        ``F_meas - (c_d xd + k_d x) = psi``: zero for mass_error and time_delay,
        ``-k_d bias`` for a displacement-sensor bias, ``-F_0`` for an offset ``F_0`` of
        the load-cell reading (``F_meas = m_f xdd_s - R``; :mod:`.effects`).
        """
        st, m = self.states, self.model
        if name in ('mass_error', 'time_delay'):
            return np.zeros(self.n)
        if name == 'sensor_bias':
            return np.full(self.n, -m.k_d * params)
        if name == 'force_offset':
            return np.full(self.n, -float(params))
        if self.lib[name].linear:
            return params * m.m_d * fx.loop_regressor(self.scenario, name, st, m)
        return m.m_d * fx.loop_term_nonlinear(name, params, st, m)

    def score(self, pred, pred_f, mask):
        """Noise-normalised mean square error: output (+ restoring force for the specimen)."""
        z = self.mse(pred, mask) / self.sigma2
        if self.force_rows:
            z += float(np.mean((self.e_r[mask] - pred_f[mask]) ** 2)) / self.sigma2_f
        return z

    @property
    def channels(self):
        """Return the number of residual channels in :meth:`score` (its white-noise floor)."""
        return 2 if self.force_rows else 1


def _solve_linear(ctx, names_lin, pnl, align=None, free_align=False):
    """Variable projection: linear parameters for fixed non-linear ones ``pnl``.

    ``align`` is the model-measurement alignment [s] (ignored when ``pnl`` holds a
    time_delay, which replaces it).  The loop effects' columns are built from the
    measured states, which already carry the measurement's timing, so only the
    nominal part is shifted.  With ``free_align`` the alignment is refitted too,
    linearised: a column ``-d/dt`` of the nominal part gives its increment.
    Returns (params, output prediction, force prediction or None, alignment [s]).
    """
    align = ctx.alignment if align is None else align
    base = ctx.predict(pnl, align)
    base_f = None
    if ctx.force_rows:
        base_f = np.zeros(ctx.n)
        for n, p in pnl.items():
            base_f += ctx.psi(n, p)
    free_align = free_align and 'time_delay' not in pnl
    nuis = ctx.force_nuisance if ctx.force_rows else np.zeros((ctx.n, 0))
    if not names_lin and not free_align and not nuis.shape[1]:
        return dict(pnl), base, base_f, align
    cols = [np.ones(ctx.n) if n == 'sensor_bias' else
            np.zeros(ctx.n) if n == 'force_offset' else ctx.column(n) for n in names_lin]
    if free_align:
        cols.append(-np.gradient(base, 1.0 / ctx.fs))
    cmat = np.column_stack(cols) if cols else np.zeros((ctx.n, 0))
    tr = ctx.train
    wx = 1.0 / math.sqrt(ctx.sigma2)
    lhs = np.hstack([cmat[tr], np.zeros((int(np.count_nonzero(tr)), nuis.shape[1]))]) * wx
    rhs = (ctx.y - base)[tr] * wx
    if ctx.force_rows:
        fcols = [ctx.psi(n, 1.0) for n in names_lin] + ([np.zeros(ctx.n)] if free_align else [])
        fmat = np.column_stack(fcols) if fcols else np.zeros((ctx.n, 0))
        wf = 1.0 / math.sqrt(ctx.sigma2_f)
        lhs = np.vstack([lhs, np.hstack([fmat[tr], nuis[tr]]) * wf])
        rhs = np.concatenate([rhs, (ctx.e_r - base_f)[tr] * wf])
    theta_all = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    theta, theta_n = theta_all[:cmat.shape[1]], theta_all[cmat.shape[1]:]
    if ctx.force_rows:
        base_f = base_f + nuis @ theta_n
    if free_align:
        step = float(np.clip(theta[-1], -ctx.align_max - align, ctx.align_max - align))
        theta = theta.copy()
        theta[-1] = step
        align = align + step
    linear = zip(names_lin, theta[:len(names_lin)], strict=True)
    params = {**pnl, **{n: float(t) for n, t in linear}}
    pred_f = base_f + fmat @ theta if ctx.force_rows else None
    nonlinear_out = ctx.nonlinear_out or any(
        n in pnl for n in ('backlash', 'velocity_saturation')) and ctx.scenario == 'actuator'
    if nonlinear_out and any(ctx.lib[n].kind == 'loop' for n in names_lin):
        return params, ctx.predict(params, align), pred_f, align
    return params, base + cmat @ theta, pred_f, align


def _search_1d(cost, lo, hi, grid, k=20, maxiter=20):
    """Grid of ``k`` points on [lo, hi] (``grid``: linspace or geomspace), bounded refinement."""
    g = grid(lo, hi, k)
    costs = [cost(p) for p in g]
    i = int(np.argmin(costs))
    a, b = g[max(i - 1, 0)], g[min(i + 1, g.size - 1)]
    res = optimize.minimize_scalar(cost, bounds=(a, b), method='bounded',
                                   options={'xatol': 1e-4 * (b - a) + 1e-12, 'maxiter': maxiter})
    return (float(res.x), float(res.fun)) if res.fun <= costs[i] else (float(g[i]), costs[i])


def _nelder_mead(cost, p0, bounds, maxiter=40):
    """Bounded Nelder-Mead polish of ``p0`` (steps relative to the bounds' widths)."""
    lo = np.array([b[0] for b in bounds])
    hi = np.array([b[1] for b in bounds])
    span = hi - lo
    p0 = np.asarray(p0, float)
    c0 = cost(p0)
    res = optimize.minimize(lambda z: cost(np.clip(p0 + z * span, lo, hi)), np.zeros(p0.size),
                            method='Nelder-Mead',
                            options={'initial_simplex': np.vstack([
                                np.zeros(p0.size), 0.06 * np.eye(p0.size)]),
                                'xatol': 1e-4, 'fatol': 0.0, 'maxiter': maxiter})
    return np.clip(p0 + res.x * span, lo, hi) if res.fun < c0 else p0


def fit_candidate(ctx, names):
    """Fit the effects ``names`` and the alignment on the training blocks.

    Returns (params, pred, pred_force, alignment [s]); with a time_delay the
    alignment is 0 (the delay takes its place).  Linear parameters and the
    (linearised) alignment increment by least squares, non-linear parameters by
    a grid and a bounded search; then two Gauss-Newton steps of the alignment
    and a final exact solve.
    """
    lin = [n for n in names if ctx.lib[n].linear]
    nl = [n for n in names if not ctx.lib[n].linear]
    free = 'time_delay' not in nl
    a0 = ctx.alignment if free else 0.0

    def cost(p):
        out = _solve_linear(ctx, lin, dict(zip(nl, p, strict=True)), a0, free_align=free)
        return ctx.score(out[1], out[2], ctx.train)

    best = []
    if len(nl) == 1:
        lo, hi = fx.nonlinear_bounds(ctx.scenario, nl[0], ctx.scales)
        g = np.linspace if nl[0] == 'time_delay' else np.geomspace
        best = [_search_1d(lambda q: cost([q]), lo, hi, g)[0]]
    elif nl:
        bounds = [fx.nonlinear_bounds(ctx.scenario, n, ctx.scales) for n in nl]
        grids = [np.linspace if n == 'time_delay' else np.geomspace for n in nl]
        pts = list(itertools.product(
            *[g(lo, hi, 7) for g, (lo, hi) in zip(grids, bounds, strict=True)]))
        costs = [cost(p) for p in pts]
        best = list(_nelder_mead(cost, pts[int(np.argmin(costs))], bounds))
    pnl = {n: float(p) for n, p in zip(nl, best, strict=True)}
    align = a0
    if free:
        for _ in range(2):
            align = _solve_linear(ctx, lin, pnl, align, free_align=True)[3]
    return _solve_linear(ctx, lin, pnl, align)


def _label(names):
    return '+'.join(sorted(names, key=fx.EFFECT_NAMES.index))


def select(ctx, progress=None, count=None):
    """Fit all candidates and decide; return a dict with the decision and the evidence.

    ``count(done, most)`` gets the candidates fitted so far and the most there can be.

    Scores are noise-normalised held-out mean square errors (:meth:`Context.score`),
    so the white-noise floor is ``ctx.channels`` and every threshold is in units
    of the noise variance.
    """
    # the nominal model with only the force channel's lag nuisance fitted (no effect)
    nominal_f = _solve_linear(ctx, [], {}, ctx.alignment)[2]
    s0 = ctx.score(ctx.y_nom, nominal_f, ctx.test)
    floor = float(ctx.channels)
    gap = max(s0 - floor, 0.0)
    fits = {}

    def add(names):
        params, pred, pred_f, align = fit_candidate(ctx, names)
        fits[_label(names)] = (params, pred, ctx.score(pred, pred_f, ctx.test), align)
        if count:
            count(len(fits), most)

    names = [n for n in fx.EFFECT_NAMES if n in ctx.lib]
    most = len(names) * (len(names) + 1) // 2            # every single and every pair
    for name in names:
        add([name])
    singles = sorted(names, key=lambda k: fits[k][2])
    for first in singles[:PAIR_TOP]:
        for other in names:
            if other != first and _label([first, other]) not in fits:
                add([first, other])
    # when nothing fitted so far comes near the noise floor, a pair of two lesser singles
    # may explain clearly more: then every pair is fitted
    if min(v[2] for v in fits.values()) - floor > PAIR_WIDEN:
        for a, b in itertools.combinations(names, 2):
            if _label([a, b]) not in fits:
                add([a, b])
    if count:
        count(len(fits), len(fits))
    if progress:
        progress(f'fitted {len(fits)} candidates')
    best1 = singles[0]
    s1 = fits[best1][2]
    pairs = [k for k in fits if '+' in k]
    best2 = min(pairs, key=lambda k: fits[k][2])
    s2 = fits[best2][2]
    # information criterion on the held-out score: n ln(score) + p ln(n) (BIC form); the
    # nominal model ('none') has one parameter, the alignment, which every candidate also
    # fits except one with a time_delay (the delay takes its place).  A more complex
    # answer must lower it.
    n_test = int(ctx.test.sum())
    ic = {k: n_test * math.log(max(v[2], 1e-300))
          + (len(v[0]) + ('time_delay' not in v[0])) * math.log(n_test)
          for k, v in fits.items()}
    ic_none = n_test * math.log(max(s0, 1e-300)) + math.log(n_test)
    choice, s_c = best1, s1
    if (s1 - s2 > max(PAIR_REL_GAIN * gap, MIN_GAIN) and s1 - s2 > PAIR_REMAINING * (s1 - floor)
            and ic[best2] < ic[best1]):
        choice, s_c = best2, s2
    gain = s0 - s_c
    # closure judged on the output alone (its floor, white noise, is known best) and on
    # all scored samples, so that an effect the held-out blocks barely excite is not
    # called unexplained
    scored = ctx.train | ctx.test
    sx0 = ctx.mse(ctx.y_nom, scored) / ctx.sigma2
    sxc = ctx.mse(fits[choice][1], scored) / ctx.sigma2
    closure = (sx0 - sxc) / (sx0 - 1.0) if sx0 > 1.0 else 0.0
    mine = set(choice.split('+'))
    rivals = [k for k in fits if not mine & set(k.split('+'))]
    rival = min(rivals, key=lambda k: ic[k]) if rivals else None
    margin = ic[rival] - ic[choice] if rival else math.inf
    reason = None
    if gain < MIN_GAIN or gain < MIN_REL_GAIN * gap or ic[choice] >= ic_none:
        decision = 'none'
    elif closure < NAME_CLOSURE and sxc - 1.0 > UNEXPLAINED_MIN:
        decision = 'unexplained'
        reason = (f'best candidate {choice} closes only {100 * closure:.0f} % of the reducible '
                  f'gap (< {100 * NAME_CLOSURE:.0f} %): an effect outside the library')
    elif margin < DISTINCT_IC:
        decision = 'unexplained'
        reason = (f'a discrepancy is there (held-out gain {gain:.3g} noise variances) but '
                  f'{choice} and {rival}, which share no effect, explain it equally well '
                  f'(information criteria {margin:.1f} apart, < {DISTINCT_IC:g}): below the '
                  'size at which the library tells them apart')
    else:
        decision = choice
    return {'decision': decision, 'best': choice, 'fits': fits, 's0': s0, 'floor': floor,
            'gap': gap, 'closure_fast': closure, 'ic': ic, 'ic_none': ic_none,
            'rival': rival, 'rival_ic_margin': margin, 'reason': reason}


def coverage(ctx, pred):
    """Amplitude coverage of the held-out blocks for an effect's contribution ``pred - y_nom``."""
    d = pred - ctx.y_nom
    tr, te = ctx.train, ctx.test
    rms_tr = float(np.sqrt(np.mean(d[tr] ** 2)))
    rms_te = float(np.sqrt(np.mean(d[te] ** 2)))
    amp = float(np.max(np.abs(ctx.y[te])) / max(np.max(np.abs(ctx.y[tr])), 1e-300))
    ratio = rms_te / rms_tr if rms_tr > 0 else 1.0
    return {'effect_rms_ratio_heldout_to_train': ratio, 'amplitude_ratio_heldout_to_train': amp,
            'ok': bool(0.5 <= ratio <= 2.0 and amp >= 0.5)}


def run_discrepancy(scenario, data, model=None, out_dir=None, rng=None, progress=None,
                    plots=True, count=None):
    """Run the workflow on ``data`` (column -> array, see :mod:`.io`); return result.json's dict.

    ``model`` is a model object of :mod:`.models`, a YAML dict, or None (Table 4
    valve #4 / Table 1 3-pole).  With ``out_dir``, writes result.json,
    updated_model.yaml, report.md and PNG plots there.  ``rng`` is accepted
    for interface stability (the workflow itself is deterministic).  ``progress(text)``
    gets the steps, ``count(done, most)`` the candidates fitted (:func:`select`).
    """
    del rng
    data = dio.validate(scenario, data)
    if model is None:
        model = models.default_model(scenario)
    elif isinstance(model, dict):
        model = models.model_from_dict(scenario, model)
    say = progress or (lambda msg: None)
    ctx = Context(scenario, data, model)
    say(f'nominal residual computed ({ctx.n} samples at {ctx.fs:g} Hz)')
    where = localize.localize(ctx, data)
    gap_tr = ctx.mse(ctx.y_nom, ctx.train) / ctx.sigma2 - 1.0
    gap_te = ctx.mse(ctx.y_nom, ctx.test) / ctx.sigma2 - 1.0
    unbalanced = bool(max(gap_tr, gap_te) > MIN_GAIN
                      and min(gap_tr, gap_te) < 0.25 * max(gap_tr, gap_te))
    if unbalanced:
        say('warning: the training and held-out blocks excite the discrepancy unequally '
            f'(residual excess {gap_tr:.3g} vs {gap_te:.3g} noise variances)')
    sel = select(ctx, progress=say, count=count)
    decision = sel['decision']
    te = ctx.test
    noise = math.sqrt(ctx.sigma2) / float(np.std(ctx.y[te]))
    before = sg.nrmse(ctx.y, ctx.y_nom, te)
    if decision == 'none':
        where['summary'] = localize.nothing_found(where)
    if decision in ('none', 'unexplained'):
        added = {}
        align = ctx.alignment
        after_pred = ctx.y_nom
    else:
        added = dict(sel['fits'][decision][0])
        align = sel['fits'][decision][3]
        if 'time_delay' in added:   # the updated model's delay is the whole delay
            added['time_delay'] += ctx.base_delay
        updated = models.with_effects(model, added)
        after_pred = fx.delay(updated.simulate(ctx.u, ctx.fs)[OUTPUT[scenario]], align, ctx.fs)
    after = sg.nrmse(ctx.y, after_pred, te)
    den = before ** 2 - noise ** 2
    gap_closed = (before ** 2 - after ** 2) / den if den > 0 else 0.0
    lib = ctx.lib
    result = {
        'scenario': scenario,
        'effect': decision,
        'parameters': {k: {lib[k].param: v, 'unit': lib[k].unit} for k, v in added.items()},
        'alignment_s': float(align),
        'alignment_samples': float(align * ctx.fs),
        'alignment_band_samples': ALIGN_SAMPLES,
        'nrmse_before': before,
        'nrmse_before_unaligned': sg.nrmse(ctx.y, ctx.y_nom_raw, te),
        'nrmse_after': after,
        'nrmse_noise': noise,
        'gap_closed': float(gap_closed),
        'candidates': {k: sg.nrmse(ctx.y, v[1], te) for k, v in sel['fits'].items()},
        'candidates_score': {k: v[2] for k, v in sel['fits'].items()},
        'candidates_parameters': {k: v[0] for k, v in sel['fits'].items()},
        'candidates_alignment_s': {k: v[3] for k, v in sel['fits'].items()},
        'best_candidate': sel['best'],
        'best_candidate_gap_closed_fast': sel['closure_fast'],
        'information_criterion': sel['ic'],
        'information_criterion_none': sel['ic_none'],
        'rival': sel['rival'],
        'rival_ic_margin': (float(sel['rival_ic_margin'])
                            if math.isfinite(sel['rival_ic_margin']) else None),
        'coverage': coverage(ctx, sel['fits'][sel['best']][1]),
        'residual_excess_train_heldout': [float(gap_tr), float(gap_te)],
        'coverage_unbalanced': unbalanced,
        'localization': where,
        'sample_rate_hz': ctx.fs,
        'samples': ctx.n,
        'updated_model': models.with_effects(model, added).to_dict(),
    }
    if decision == 'unexplained':
        result['unexplained_note'] = sel['reason']
    say(f'alignment {1e3 * align:+.3f} ms ({align * ctx.fs:+.2f} samples; the DAQ-convention '
        f'band is +-{ALIGN_SAMPLES:g} samples)')
    say(f"effect: {decision}  NRMSE held-out {before:.4f} -> {after:.4f} "
        f'(noise {noise:.4f}), gap closed {gap_closed:.2f}')
    if out_dir is not None:
        report.write_outputs(out_dir, result, ctx, after_pred, plots=plots)
    return result
