"""Reference baselines for the discrepancy self-test: pysindy (SINDy) and sysidentpy (NARX).

Issue 7 asks the workflow to do better than both; this module runs them on
the *same* synthetic records the workflow sees (:func:`.selftest.make_record`)
so that ``rths bench discrepancy --baselines`` can compare.  Both packages
are imported lazily (they are optional for the workflow itself).

SINDy (pysindy, STLSQ) on the model residual dynamics
------------------------------------------------------
Derivatives come from the MEASURED output by pysindy's differentiation
(``diff='fd'``: ``ps.FiniteDifference`` (2nd order); ``'smoothed'``:
``ps.SmoothedFiniteDifference``, Savitzky-Golay then finite differences);
true velocities are never used.  Target and candidate functions:

* specimen (eq. 46): residual acceleration
  ``r = xdd + xdd_s + (c_d xd + k_d x) / m_d`` (zero for the nominal model).
  The library holds no acceleration term: ``xdd`` is in the target, and a
  library column sharing its finite-difference noise is fitted with
  coefficient ~1 whatever the data (errors in variables).  A mass error
  makes ``r = dm (c_d xd + k_d x) / (m_d (m_d + dm))``, i.e. a proportional
  stiffness + damping error, so SINDy has no way to name mass_error here;
* actuator (``y = G(s) (u - q)``, ``G = n0 / den(s)``): residual load
  ``q = u - den(D) y / n0`` (3rd derivative of the measurement for the
  Table 1 3-pole model; the command is shifted half a sample to the
  measurement instants of the ZOH timing convention of :mod:`.models`).

Library (the workflow's parameter-linear candidates) and the explicit
mapping of each term to an effect name (:data:`TERM_EFFECT`)::

    x -> stiffness_error      v -> viscous_damping_error   sign(v) -> coulomb_friction
    x^3 -> cubic_stiffness    a -> mass_error (actuator)   1 -> sensor_bias

backlash, time_delay and velocity_saturation have no SINDy term (their
parameter enters non-linearly; a fixed-parameter library term would be a
guess of the answer), so SINDy can only name them wrongly or ``none``.
``named`` = the effect of the surviving term with the largest contribution
``rms(xi_j theta_j)``; ``'none'`` if no term survives (SINDy has no notion
of ``unexplained``).  ``named_set`` = all effects with a surviving term,
joined by ``+`` in library order (used for the pair cases).

NARX (sysidentpy, FROLS)
------------------------
Polynomial NARX of degree 2, ``ylag = xlag = 2``, AIC order selection,
least squares, input -> measured output (both scaled to unit standard
deviation), fitted on the first half of the record; free-run NRMSE on the
second half.  Its regressors are lagged monomials such as ``y(k-1)x1(k-2)``;
no physical name follows from them, so its naming accuracy is 0 by
construction (no mapping is defined).
"""

import warnings

import numpy as np

from rths_discrepancy import effects as fx
from rths_discrepancy import models

#: Term of the SINDy library -> effect it names.
TERM_EFFECT = {
    'x': 'stiffness_error', 'v': 'viscous_damping_error', 'sign(v)': 'coulomb_friction',
    'x^3': 'cubic_stiffness', 'a': 'mass_error', '1': 'sensor_bias',
}
TERMS = tuple(TERM_EFFECT)
#: pysindy's STLSQ default threshold.
DEFAULT_THRESHOLD = 0.1
#: Thresholds of the (separately reported) sweep, in the target's SI units per term unit.
THRESHOLD_SWEEP = (1e-4, 1e-3, 1e-2, 1e-1, 1.0, 10.0)
DIFFS = ('fd', 'smoothed')


def _differentiator(diff, d):
    # lazy: optional dependency (pysindy)
    import pysindy as ps
    if diff == 'fd':
        return ps.FiniteDifference(order=2, d=d)
    if diff == 'smoothed':
        return ps.SmoothedFiniteDifference(d=d)
    raise ValueError(f'diff must be one of {", ".join(DIFFS)}, not {diff!r}')


def _derivative(y, dt, d, diff):
    """``d``-th derivative of ``y`` by pysindy's finite differences."""
    return np.ravel(_differentiator(diff, d)(np.asarray(y, float).reshape(-1, 1), dt))


def sindy_problem(scenario, data, model=None, diff='fd', velocity=None):
    """Return (theta [n, 6], target [n], feature names) of the residual dynamics.

    ``velocity`` (optional) replaces the finite-difference velocity by a given
    one (the unit test's "clean measured velocity"); everything else is still
    differentiated from the measured output.
    """
    model = model or models.default_model(scenario)
    t = np.asarray(data['time'], float)
    dt = float(t[1] - t[0])
    if scenario == 'specimen':
        x = np.asarray(data['rel_disp'], float)
        u = np.asarray(data['base_accel'], float)
        v = _derivative(x, dt, 1, diff) if velocity is None else np.asarray(velocity, float)
        a = _derivative(x, dt, 2, diff)
        target = a + u + (model.c_d * v + model.k_d * x) / model.m_d
        acc_term = None
    elif scenario == 'actuator':
        if model.kind != 'continuous':
            raise ValueError('SINDy baseline needs a continuous actuator model (num, den in s)')
        num = np.trim_zeros(np.asarray(model.num, float), 'f')
        if num.size != 1:
            raise ValueError('SINDy baseline needs an actuator model without zeros (constant '
                             'numerator), e.g. the Table 1 3-pole model')
        den = np.asarray(model.den, float)
        x = np.asarray(data['measured'], float)
        u = np.asarray(data['command'], float)
        u_at_y = 0.5 * (u + np.concatenate([u[1:], u[-1:]]))  # ZOH: y_k read at t_{k+1}
        order = den.size - 1
        ders = [x] + [_derivative(x, dt, d, diff) for d in range(1, order + 1)]
        if velocity is not None:
            ders[1] = np.asarray(velocity, float)
        lhs = sum(den[order - d] * ders[d] for d in range(order + 1))
        target = u_at_y - lhs / num[0]
        v = ders[1]
        acc_term = ders[2] if order >= 2 else _derivative(x, dt, 2, diff)
    else:
        raise ValueError(f'unknown scenario {scenario!r}; use one of {", ".join(fx.SCENARIOS)}')
    cols = {'x': x, 'v': v, 'sign(v)': np.sign(v), 'x^3': x ** 3, 'a': acc_term,
            '1': np.ones_like(x)}
    names = [k for k in TERMS if cols[k] is not None]
    return np.column_stack([cols[k] for k in names]), target, names


def sindy_fit(theta, target, threshold=DEFAULT_THRESHOLD, dt=1.0, names=TERMS):
    """Fit SINDy (STLSQ at ``threshold``) with the precomputed library; return the result.

    The library is passed through ``ps.IdentityLibrary`` (each column one
    candidate function) with the residual as the derivative target.
    """
    # lazy: optional dependency (pysindy)
    import pysindy as ps
    mdl = ps.SINDy(optimizer=ps.STLSQ(threshold=threshold),
                   feature_library=ps.IdentityLibrary())
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        mdl.fit(theta, t=dt, x_dot=np.asarray(target, float).reshape(-1, 1),
                feature_names=list(names))
    coef = np.ravel(mdl.coefficients())
    contrib = {names[j]: float(np.sqrt(np.mean((coef[j] * theta[:, j]) ** 2)))
               for j in range(len(names)) if coef[j] != 0.0}
    by_effect = {}
    for term, c in contrib.items():
        eff = TERM_EFFECT[term]
        by_effect[eff] = by_effect.get(eff, 0.0) + c
    named = max(by_effect, key=by_effect.get) if by_effect else 'none'
    kept = [e for e in fx.EFFECT_NAMES if e in by_effect]
    return {'threshold': threshold, 'coefficients': dict(zip(names, map(float, coef), strict=True)),
            'contributions': contrib, 'named': named,
            'named_set': '+'.join(kept) if kept else 'none'}


def sindy_baseline(scenario, data, model=None, diff='fd', thresholds=(DEFAULT_THRESHOLD,),
                   velocity=None):
    """Fit SINDy to one record at each of ``thresholds``; return {threshold: fit result}."""
    theta, target, names = sindy_problem(scenario, data, model=model, diff=diff,
                                         velocity=velocity)
    dt = float(data['time'][1] - data['time'][0])
    return {float(th): sindy_fit(theta, target, th, dt, names) for th in thresholds}


def narx_baseline(scenario, data, degree=2, ylag=2, xlag=2, max_terms=10):
    """Polynomial NARX (FROLS) input -> measured output; regressors as text and free-run NRMSE.

    Fitted on the first half of the record, simulated free-run (``steps_ahead=None``)
    on the second half; NRMSE = rms error / std of the measured output there.
    """
    # lazy: optional dependency (sysidentpy)
    from sysidentpy.basis_function import Polynomial
    from sysidentpy.model_structure_selection import FROLS
    from sysidentpy.parameter_estimation import LeastSquares
    from sysidentpy.utils.display_results import results
    inp = 'base_accel' if scenario == 'specimen' else 'command'
    out = 'rel_disp' if scenario == 'specimen' else 'measured'
    u = np.asarray(data[inp], float)
    y = np.asarray(data[out], float)
    su, sy = float(np.std(u)) or 1.0, float(np.std(y)) or 1.0
    u, y = (u / su).reshape(-1, 1), (y / sy).reshape(-1, 1)
    half = y.shape[0] // 2
    mdl = FROLS(order_selection=True, n_info_values=max_terms, info_criteria='aic',
                ylag=ylag, xlag=xlag, estimator=LeastSquares(),
                basis_function=Polynomial(degree=degree))
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')
        mdl.fit(X=u[:half], y=y[:half])
        lag = mdl.max_lag
        yhat = mdl.predict(X=u[half:], y=y[half:half + lag])
    e = (y[half:] - yhat)[lag:]
    nrmse = float(np.sqrt(np.mean(e ** 2)) / np.std(y[half:][lag:]))
    table = results(mdl.final_model, mdl.theta, mdl.err, mdl.n_terms,
                    err_precision=4, dtype='sci')
    return {'terms': [row[0] for row in table], 'parameters': [row[1] for row in table],
            'free_run_nrmse': nrmse if np.isfinite(nrmse) else None,
            'settings': {'degree': degree, 'ylag': ylag, 'xlag': xlag,
                         'info_criteria': 'aic', 'max_terms': max_terms}}


def run_baselines(scenario, data):
    """Both baselines on one record (what ``rths bench discrepancy --baselines`` stores)."""
    out = {'sindy': {}}
    for diff in DIFFS:
        fits = sindy_baseline(scenario, data, diff=diff, thresholds=THRESHOLD_SWEEP)
        out['sindy'][diff] = {repr(th): {k: f[k] for k in ('named', 'named_set')}
                              for th, f in fits.items()}
        if diff == 'fd':
            out['sindy_default'] = fits[DEFAULT_THRESHOLD]
    try:
        out['narx'] = narx_baseline(scenario, data)
    except Exception as err:  # a diverging free run must not stop the benchmark
        out['narx'] = {'error': f'{type(err).__name__}: {err}'}
    return out


def _correct(named, named_set, expected):
    """Return True if SINDy is correct: the top effect (single/none), the kept set (pairs)."""
    if '+' in expected:
        return named_set == expected
    return named == expected


def _named_by(*path):
    """Return ``row -> (named, named_set)`` of the baseline result at ``path`` of a row."""
    def get(row):
        result = row['baselines']
        for part in path:
            result = result[part]
        return result['named'], result['named_set']
    return get


def summarize(rows):
    """Baseline summary over benchmark ``rows`` (each with a 'baselines' entry)."""
    rows = [r for r in rows if 'baselines' in r]
    if not rows:
        return None
    controls = [r for r in rows if r['expected'] == 'none']

    def rate(get):
        ok = sum(_correct(*get(r), r['expected']) for r in rows)
        false = sum(get(r)[0] != 'none' for r in controls)
        return 100.0 * ok / len(rows), false

    default = rate(_named_by('sindy_default'))
    sweep = {}
    for diff in DIFFS:
        for th in THRESHOLD_SWEEP:
            key = repr(float(th))
            pct, false = rate(_named_by('sindy', diff, key))
            sweep[f'{diff}@{key}'] = {'correct_naming_percent': pct,
                                      'false_effects_on_controls': false}
    best = max(sweep, key=lambda k: (sweep[k]['correct_naming_percent'],
                                     -sweep[k]['false_effects_on_controls']))
    nrmse = [r['baselines']['narx'].get('free_run_nrmse') for r in rows]
    nrmse = [v for v in nrmse if v is not None]
    examples = []
    seen = set()
    for r in rows:
        key = (r['scenario'], r['expected'])
        if r['expected'] in ('none', 'coulomb_friction', 'cubic_stiffness', 'backlash') \
                and key not in seen and 'terms' in r['baselines']['narx']:
            seen.add(key)
            examples.append({'scenario': r['scenario'], 'label': r['label'],
                             'seed': r['seed'], 'terms': r['baselines']['narx']['terms'],
                             'free_run_nrmse': r['baselines']['narx']['free_run_nrmse']})
    sindy_conf = {}
    for r in rows:
        got = r['baselines']['sindy_default']['named']
        sindy_conf.setdefault(r['expected'], {}).setdefault(got, 0)
        sindy_conf[r['expected']][got] += 1
    return {
        'cases': len(rows), 'controls': len(controls),
        'definitions': 'correct: SINDy top-contribution effect == expected (pair cases: the '
                       'set of effects with surviving terms == expected pair); false effect: '
                       'a control case whose top effect is not none; SINDy cannot answer '
                       'unexplained; NARX names nothing (0 % by construction)',
        'sindy_default': {'diff': 'fd', 'threshold': DEFAULT_THRESHOLD,
                          'correct_naming_percent': default[0],
                          'false_effects_on_controls': default[1],
                          'confusion_matrix': sindy_conf},
        'sindy_sweep': sweep,
        'sindy_best_of_sweep': {'setting': best, **sweep[best],
                                'note': 'chosen after seeing the answers (oracle tuning)'},
        'narx': {'correct_naming_percent': 0.0,
                 'median_free_run_nrmse': float(np.median(nrmse)) if nrmse else None,
                 'failed_fits': len(rows) - len(nrmse), 'examples': examples[:6]},
    }
