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
4. Decision on the held-out blocks, with the white-noise floor ``sigma^2``
   (:func:`.signals.noise_variance`) and ``S`` the held-out mean square error:
   no effect is named unless its gain ``S_0 - S`` exceeds ``MIN_GAIN *
   sigma^2`` and ``MIN_REL_GAIN`` of the reducible gap ``S_0 - sigma^2``; a
   pair replaces the best single only if it removes a further
   ``PAIR_REL_GAIN`` of the gap and ``PAIR_REMAINING`` of what the single
   left; if the winner closes less than ``NAME_CLOSURE`` of the gap, the
   answer is ``unexplained``.
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
from rths_discrepancy import models
from rths_discrepancy import signals as sg

#: Held-out gain needed to name anything, in units of the noise variance.
MIN_GAIN = 0.2
#: ... and as a fraction of the reducible gap S_0 - sigma^2.
MIN_REL_GAIN = 0.2
#: Extra fraction of the gap a pair must close beyond its best single member.
PAIR_REL_GAIN = 0.03
#: ... and the fraction of what the single left that the pair must remove.
PAIR_REMAINING = 0.5
#: Fraction of the gap the winner must close to be named (else 'unexplained').
NAME_CLOSURE = 0.8
#: Number of best single effects that are combined with every other effect.
PAIR_TOP = 3

INPUT = {'specimen': 'base_accel', 'actuator': 'command'}
OUTPUT = {'specimen': 'rel_disp', 'actuator': 'measured'}
_OUTPUT_OPS = {'specimen': ('time_delay', 'sensor_bias'),
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
        self.out_eff = {k: v for k, v in model.effects.items() if k in ops}
        core = models.with_effects(model, {})
        core.effects = {k: v for k, v in model.effects.items() if k not in ops}
        self.y_core = core.simulate(self.u, self.fs)[OUTPUT[scenario]]
        self.y_nom = fx.apply_output_ops(scenario, self.y_core, self.out_eff, self.fs)
        self.b, self.a = model.linear_filter(self.fs)
        st = sg.states(self.y, self.fs)
        if scenario == 'actuator':  # load held over sample k acts from the end of sample k-1
            st = {k: (np.concatenate([v[:1], v[:-1]]) if k != 'fc' else v)
                  for k, v in st.items()}
        st['u'] = self.u
        self.states = st
        self.sign = 1.0 if scenario == 'specimen' else -1.0
        self.sigma2 = sg.noise_variance(self.y - self.y_nom, self.fs)
        self.train, self.test = sg.block_masks(self.n)
        self.scales = {'y_rms': float(np.std(self.y)), 'v_rms': float(np.std(st['v'])),
                       'v_max': float(np.max(np.abs(st['v'])))}
        self._cols = {}
        self.nonlinear_out = scenario == 'actuator' and any(
            k in self.out_eff for k in ('backlash', 'velocity_saturation'))

    def column(self, name):
        """Filtered regressor ``G[s phi]`` of a linear loop effect (cached)."""
        if name not in self._cols:
            phi = fx.loop_regressor(self.scenario, name, self.states, self.model)
            self._cols[name] = lfilter(self.b, self.a, self.sign * phi)
        return self._cols[name]

    def predict(self, params):
        """Fast prediction of the model plus the effects ``params`` ({name: value})."""
        y = self.y_core.copy()
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
                                   if self.lib[k].kind == 'output'}}
        return fx.apply_output_ops(self.scenario, y, outs, self.fs)

    def mse(self, pred, mask):
        """Mean square error of ``pred`` on ``mask``."""
        return float(np.mean((self.y[mask] - pred[mask]) ** 2))


def _solve_linear(ctx, names_lin, pnl):
    """Variable projection: linear parameters for fixed non-linear ones ``pnl``."""
    base = ctx.predict(pnl)
    if not names_lin:
        return dict(pnl), base
    cols = []
    for n in names_lin:
        if n == 'sensor_bias':
            cols.append(np.ones(ctx.n))
        else:
            c = ctx.column(n)
            if 'time_delay' in pnl:
                c = fx.delay(c, pnl['time_delay'], ctx.fs)
            cols.append(c)
    cmat = np.column_stack(cols)
    tr = ctx.train
    theta = np.linalg.lstsq(cmat[tr], (ctx.y - base)[tr], rcond=None)[0]
    params = {**pnl, **{n: float(t) for n, t in zip(names_lin, theta)}}
    nonlinear_out = ctx.nonlinear_out or any(
        n in pnl for n in ('backlash', 'velocity_saturation')) and ctx.scenario == 'actuator'
    if nonlinear_out and any(ctx.lib[n].kind == 'loop' for n in names_lin):
        return params, ctx.predict(params)
    return params, base + cmat @ theta


def fit_candidate(ctx, names):
    """Fit the effects ``names`` on the training blocks; return (params, prediction)."""
    lin = [n for n in names if ctx.lib[n].linear]
    nl = [n for n in names if not ctx.lib[n].linear]
    if not nl:
        return _solve_linear(ctx, lin, {})
    bounds = [fx.nonlinear_bounds(ctx.scenario, n, ctx.scales) for n in nl]

    def grid(n, lo, hi, k):
        return np.linspace(lo, hi, k) if n == 'time_delay' else np.geomspace(lo, hi, k)

    def cost(p):
        _, pred = _solve_linear(ctx, lin, dict(zip(nl, p)))
        return ctx.mse(pred, ctx.train)

    if len(nl) == 1:
        g = grid(nl[0], *bounds[0], 24)
        costs = [cost([p]) for p in g]
        i = int(np.argmin(costs))
        lo, hi = g[max(i - 1, 0)], g[min(i + 1, g.size - 1)]
        res = optimize.minimize_scalar(lambda p: cost([p]), bounds=(lo, hi), method='bounded',
                                       options={'xatol': 1e-4 * (hi - lo) + 1e-12,
                                                'maxiter': 30})
        best = [res.x] if res.fun <= costs[i] else [g[i]]
    else:
        grids = [grid(n, lo, hi, 9) for n, (lo, hi) in zip(nl, bounds)]
        pts = list(itertools.product(*grids))
        costs = [cost(p) for p in pts]
        p0 = np.array(pts[int(np.argmin(costs))])
        span = np.array([hi - lo for lo, hi in bounds])
        res = optimize.minimize(lambda z: cost(np.clip(p0 + z * span, [b[0] for b in bounds],
                                                        [b[1] for b in bounds])),
                                np.zeros(len(nl)), method='Nelder-Mead',
                                options={'initial_simplex': np.vstack([
                                    np.zeros(len(nl)), 0.06 * np.eye(len(nl))]),
                                    'xatol': 1e-4, 'fatol': 0.0, 'maxiter': 60})
        best = np.clip(p0 + res.x * span, [b[0] for b in bounds], [b[1] for b in bounds])
        if res.fun > min(costs):
            best = p0
    return _solve_linear(ctx, lin, {n: float(p) for n, p in zip(nl, best)})


def _label(names):
    return '+'.join(sorted(names, key=fx.EFFECT_NAMES.index))


def select(ctx, progress=None):
    """Fit all candidates and decide; return a dict with the decision and the evidence."""
    s0 = ctx.mse(ctx.y_nom, ctx.test)
    sig2 = ctx.sigma2
    gap = max(s0 - sig2, 0.0)
    fits = {}
    for name in fx.EFFECT_NAMES:
        params, pred = fit_candidate(ctx, [name])
        fits[name] = (params, pred, ctx.mse(pred, ctx.test))
    singles = sorted(fx.EFFECT_NAMES, key=lambda k: fits[k][2])
    for first in singles[:PAIR_TOP]:
        for other in fx.EFFECT_NAMES:
            label = _label([first, other])
            if other == first or label in fits:
                continue
            params, pred = fit_candidate(ctx, [first, other])
            fits[label] = (params, pred, ctx.mse(pred, ctx.test))
    if progress:
        progress(f'fitted {len(fits)} candidates')
    best1 = singles[0]
    s1 = fits[best1][2]
    pairs = [k for k in fits if '+' in k and best1 in k.split('+')]
    best2 = min(pairs, key=lambda k: fits[k][2])
    s2 = fits[best2][2]
    choice, s_c = best1, s1
    if s1 - s2 > max(PAIR_REL_GAIN * gap, MIN_GAIN * sig2) and s1 - s2 > PAIR_REMAINING * (
            s1 - sig2):
        choice, s_c = best2, s2
    gain = s0 - s_c
    closure = gain / gap if gap > 0 else 0.0
    if gain < MIN_GAIN * sig2 or gain < MIN_REL_GAIN * gap:
        decision = 'none'
    elif closure < NAME_CLOSURE:
        decision = 'unexplained'
    else:
        decision = choice
    n_test = int(ctx.test.sum())
    ic = {k: n_test * math.log(max(v[2], 1e-300)) + len(k.split('+')) * math.log(n_test)
          for k, v in fits.items()}
    return {'decision': decision, 'best': choice, 'fits': fits, 's0': s0, 'sigma2': sig2,
            'gap': gap, 'closure_fast': closure, 'ic': ic}


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
                    plots=True):
    """Run the workflow on ``data`` (column -> array, see :mod:`.io`); return result.json's dict.

    ``model`` is a model object of :mod:`.models`, a YAML dict, or None (Table 4
    valve #4 / Table 1 3-pole).  With ``out_dir``, writes result.json,
    updated_model.yaml, report.md and PNG plots there.  ``rng`` is accepted
    for interface stability (the workflow itself is deterministic).
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
    from rths_discrepancy import localize
    where = localize.localize(ctx, data)
    sel = select(ctx, progress=say)
    decision = sel['decision']
    te = ctx.test
    noise = math.sqrt(ctx.sigma2) / float(np.std(ctx.y[te]))
    before = sg.nrmse(ctx.y, ctx.y_nom, te)
    if decision in ('none', 'unexplained'):
        added = {}
        after_pred = ctx.y_nom
    else:
        added = sel['fits'][decision][0]
        updated = models.with_effects(model, added)
        after_pred = updated.simulate(ctx.u, ctx.fs)[OUTPUT[scenario]]
    after = sg.nrmse(ctx.y, after_pred, te)
    den = before ** 2 - noise ** 2
    gap_closed = (before ** 2 - after ** 2) / den if den > 0 else 0.0
    lib = ctx.lib
    result = {
        'scenario': scenario,
        'effect': decision,
        'parameters': {k: {lib[k].param: v, 'unit': lib[k].unit} for k, v in added.items()},
        'nrmse_before': before,
        'nrmse_after': after,
        'nrmse_noise': noise,
        'gap_closed': float(gap_closed),
        'candidates': {k: math.sqrt(v[2]) / float(np.std(ctx.y[te]))
                       for k, v in sel['fits'].items()},
        'candidates_parameters': {k: v[0] for k, v in sel['fits'].items()},
        'best_candidate': sel['best'],
        'best_candidate_gap_closed_fast': sel['closure_fast'],
        'information_criterion': sel['ic'],
        'coverage': coverage(ctx, sel['fits'][sel['best']][1]),
        'localization': where,
        'sample_rate_hz': ctx.fs,
        'samples': ctx.n,
        'updated_model': models.with_effects(model, added).to_dict(),
    }
    if decision == 'unexplained':
        result['unexplained_note'] = (
            f"best candidate {sel['best']} closes only {100 * sel['closure_fast']:.0f} % of the "
            f'reducible gap (< {100 * NAME_CLOSURE:.0f} %): an effect outside the library')
    say(f"effect: {decision}  NRMSE held-out {before:.4f} -> {after:.4f} "
        f'(noise {noise:.4f}), gap closed {gap_closed:.2f}')
    if out_dir is not None:
        from rths_discrepancy import report
        report.write_outputs(out_dir, result, ctx, after_pred, plots=plots)
    return result
