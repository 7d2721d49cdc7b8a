"""Self-test of the discrepancy workflow: synthetic records with a hidden effect.

Specimen records: the Table 4 valve #4 DTM (m_d = 258.35 kg, c_d = 491.6
N s/m, k_d = 80 810 N/m) driven through eq. 46 by a BLWN base acceleration
(0~10 Hz, 1 m/s^2 peak, the seed's DTM characterisation bands of section
5.1.2); actuator records: the Table 1 3-pole model driven by a BLWN command
(0~20 Hz, 10 mm peak; section 4.3.1 uses 2.54-38.1 mm).  The hidden effect is
simulated with the full non-linear model (finer steps than the workflow),
then white Gaussian noise is added to every measured channel (``noise`` x its
standard deviation).

Effect sizes at strength 1 (``strength=0.2`` divides them by five; for the
velocity saturation the velocity deficit ``1 - v_sat / v_peak`` = 0.6 at full
strength scales with ``sqrt(strength)``, 0.27 at one fifth, because with a
deficit of 0.12 only one or two peaks per record reach the limit): see
:func:`effect_size`.  Extra effects that are *not* in the library:
``_stribeck`` (Stribeck friction, the library has Coulomb only) and ``_lag``
(a first-order lag of the measurement chain).
"""

import numpy as np

from rths_discrepancy import effects as fx
from rths_discrepancy import models

DURATION_S = 16.0
QUICK_DURATION_S = 8.0
FS_HZ = 1024.0
NOISE = 0.005


def excitation(scenario, duration_s, fs, rng):
    """Return the input of a synthetic record (BLWN with 0.5 s tapers)."""
    from rths_numerical.signals import blwn
    if scenario == 'specimen':
        return blwn(duration_s, fs, 10.0, 1.0, rng=rng, taper_s=0.5)
    return blwn(duration_s, fs, 20.0, 0.010, rng=rng, taper_s=0.5)


def effect_size(scenario, name, strength, scales, model):
    """Parameter of ``name`` at ``strength`` for a record with signal ``scales``.

    ``scales``: 'y_rms', 'y_max', 'v_max' of the nominal response.
    """
    s = strength
    if scenario == 'specimen':
        table = {
            'coulomb_friction': 8.0 * s,                        # N (mu ~ 0.003 on 258 kg)
            'viscous_damping_error': 0.5 * model.c_d * s,       # N s/m
            'stiffness_error': 0.05 * model.k_d * s,            # N/m
            'cubic_stiffness': 0.1 * model.k_d * s / scales['y_max'] ** 2,  # N/m^3
            'mass_error': 0.05 * model.m_d * s,                 # kg
            'backlash': 0.05 * scales['y_rms'] * s,             # m
            'time_delay': 0.005 * s,                            # s
            'velocity_saturation': scales['v_max'] * (1.0 - 0.6 * s ** 0.5),  # m/s
            'sensor_bias': 0.1 * scales['y_rms'] * s,           # m
        }
    else:
        table = {
            'coulomb_friction': 0.1 * scales['y_rms'] * s,      # m
            'viscous_damping_error': 0.002 * s,                 # s
            'stiffness_error': 0.05 * s,                        # -
            'cubic_stiffness': 0.3 * s / scales['y_max'] ** 2,  # 1/m^2
            'mass_error': 2e-5 * s,                             # s^2
            'backlash': 0.1 * scales['y_rms'] * s,              # m
            'time_delay': 0.002 * s,                            # s
            'velocity_saturation': scales['v_max'] * (1.0 - 0.6 * s ** 0.5),  # m/s
            'sensor_bias': 0.1 * scales['y_rms'] * s,           # m
        }
    return table[name]


def make_record(scenario, hidden, seed, duration_s=DURATION_S, fs=FS_HZ, noise=NOISE,
                strength=1.0, model=None):
    """Synthetic record with the ``hidden`` effects; return (data, true_params).

    ``hidden`` is a list of effect names (library names, '_stribeck', '_lag');
    their sizes follow :func:`effect_size` at ``strength``; an entry
    '_noise:0.02' sets the relative noise level instead.
    """
    rng = np.random.default_rng(seed)
    model = model or models.default_model(scenario)
    u = excitation(scenario, duration_s, fs, rng)
    out = 'rel_disp' if scenario == 'specimen' else 'measured'
    nominal = model.simulate(u, fs)[out]
    vel = np.gradient(nominal, 1.0 / fs)
    scales = {'y_rms': float(np.std(nominal)), 'y_max': float(np.max(np.abs(nominal))),
              'v_max': float(np.max(np.abs(vel)))}
    truth = {}
    for name in hidden:
        if name.startswith('_noise:'):
            noise = float(name.split(':')[1])
        elif name == '_stribeck':
            fc = effect_size(scenario, 'coulomb_friction', strength, scales, model)
            truth['_stribeck'] = (fc, 1.6 * fc, 0.1 * scales['v_max'])
        elif name == '_lag':
            truth['_lag'] = 0.06 if scenario == 'specimen' else 0.015
        else:
            truth[name] = effect_size(scenario, name, strength, scales, model)
    true_model = models.with_effects(model, {})
    true_model.effects = dict(truth)
    sim = true_model.simulate(u, fs, substeps=4)
    t = np.arange(u.size) / fs
    inp = 'base_accel' if scenario == 'specimen' else 'command'
    data = {'time': t, inp: u.copy()}
    if scenario == 'specimen':
        data['base_accel'] = u + noise * np.std(u) * rng.standard_normal(u.size)
        for ch in ('rel_disp', 'force'):
            data[ch] = sim[ch] + noise * np.std(sim[ch]) * rng.standard_normal(u.size)
    else:
        data['measured'] = sim['measured'] + noise * np.std(sim['measured']) * \
            rng.standard_normal(u.size)
    return data, truth


#: Benchmark case groups: (label, hidden effects, strength, expected answer).
def bench_cases(quick=False):
    """List of (scenario, label, hidden, strength, expected) for the benchmark."""
    cases = []
    pairs = [('coulomb_friction', 'stiffness_error'), ('time_delay', 'sensor_bias'),
             ('viscous_damping_error', 'cubic_stiffness'), ('backlash', 'mass_error')]
    for sc in fx.SCENARIOS:
        cases.append((sc, 'control', [], 1.0, 'none'))
        cases.append((sc, 'control(2% noise)', ['_noise:0.02'], 1.0, 'none'))
        for name in fx.EFFECT_NAMES:
            cases.append((sc, name, [name], 1.0, name))
            if not quick:
                cases.append((sc, name + '@0.2', [name], 0.2, name))
        for p in (pairs[:2] if quick else pairs):
            label = '+'.join(sorted(p, key=fx.EFFECT_NAMES.index))
            cases.append((sc, label, list(p), 1.0, label))
        cases.append((sc, 'stribeck(form mismatch)', ['_stribeck'], 1.0, 'coulomb_friction'))
        cases.append((sc, 'first_order_lag(no candidate)', ['_lag'], 1.0, 'unexplained'))
    return cases


def run_case(args):
    """Run one benchmark case.

    ``args`` = (scenario, label, hidden, strength, expected, seed[, duration_s[,
    baselines]]); with ``baselines`` true, pysindy and sysidentpy also run on the
    same record (:mod:`.baselines`) and the row gets a 'baselines' entry.
    """
    import time

    from rths_discrepancy.workflow import run_discrepancy
    scenario, label, hidden, strength, expected, seed = args[:6]
    duration = args[6] if len(args) > 6 else DURATION_S
    with_baselines = bool(args[7]) if len(args) > 7 else False
    t0 = time.perf_counter()
    data, truth = make_record(scenario, hidden, seed, strength=strength, duration_s=duration)
    res = run_discrepancy(scenario, data, plots=False)
    errors = {}
    for name, val in truth.items():
        if name.startswith('_') or name not in res['parameters']:
            continue
        got = res['parameters'][name][fx.LIBRARY[scenario][name].param]
        errors[name] = abs(got - val) / abs(val)
    row = {'scenario': scenario, 'label': label, 'strength': strength, 'seed': seed,
            'expected': expected, 'named': res['effect'], 'correct': res['effect'] == expected,
            'truth': {k: (list(v) if isinstance(v, tuple) else v) for k, v in truth.items()},
            'parameters': res['parameters'], 'parameter_rel_errors': errors,
            'nrmse_before': res['nrmse_before'], 'nrmse_after': res['nrmse_after'],
            'nrmse_noise': res['nrmse_noise'], 'gap_closed': res['gap_closed'],
            'best_candidate': res['best_candidate'],
            'best_closure_fast': res['best_candidate_gap_closed_fast'],
            'seconds': time.perf_counter() - t0}
    if with_baselines:
        from rths_discrepancy import baselines
        row['baselines'] = baselines.run_baselines(scenario, data)
    return row


def run_bench(seeds=3, quick=False, workers=2, progress=None, baselines=False) -> dict:
    """Run the self-test benchmark; return the summary (confusion matrix, rates, details).

    Targets of issue 7: >= 95 % correct naming, 0 false effects on the
    controls, median gap_closed >= 0.9 (over cases whose answer is an effect).
    ``baselines``: also run pysindy / sysidentpy on every record; the summary
    gets a 'baselines' entry (:func:`.baselines.summarize`).
    """
    import time
    t0 = time.perf_counter()
    duration = QUICK_DURATION_S if quick else DURATION_S
    jobs = [case + (seed, duration, baselines) for seed in range(seeds)
            for case in bench_cases(quick)]
    rows = []
    say = progress or (lambda msg: None)
    if workers > 1:
        import multiprocessing as mp
        with mp.get_context('fork').Pool(workers) as pool:
            for row in pool.imap_unordered(run_case, jobs):
                rows.append(row)
                say(_progress_line(len(rows), len(jobs), row))
    else:
        for job in jobs:
            rows.append(run_case(job))
            say(_progress_line(len(rows), len(jobs), rows[-1]))
    rows.sort(key=lambda r: (r['scenario'], r['label'], r['seed']))
    confusion = {}
    for r in rows:
        confusion.setdefault(r['expected'], {}).setdefault(r['named'], 0)
        confusion[r['expected']][r['named']] += 1
    controls = [r for r in rows if r['expected'] == 'none']
    named = [r for r in rows if r['expected'] not in ('none', 'unexplained')]
    recov = [e for r in rows if r['correct'] and r['strength'] == 1.0
             for e in r['parameter_rel_errors'].values()]
    recov_weak = [e for r in rows if r['correct'] and r['strength'] != 1.0
                  for e in r['parameter_rel_errors'].values()]
    summary = {
        'cases': len(rows),
        'seeds': seeds,
        'quick': quick,
        'record_duration_s': duration,
        'correct_naming_percent': 100.0 * sum(r['correct'] for r in rows) / len(rows),
        'false_effects_on_controls': sum(r['named'] != 'none' for r in controls),
        'controls': len(controls),
        'median_gap_closed': float(np.median([r['gap_closed'] for r in named])),
        'parameters_within_15_percent_full_strength':
            (sum(e <= 0.15 for e in recov), len(recov)),
        'parameters_within_15_percent_one_fifth_strength':
            (sum(e <= 0.15 for e in recov_weak), len(recov_weak)),
        'max_parameter_error_full_strength': max(recov) if recov else None,
        'confusion_matrix': confusion,
        'wrong': [{k: r[k] for k in ('scenario', 'label', 'seed', 'named', 'best_candidate',
                                     'best_closure_fast')} for r in rows if not r['correct']],
        'wall_time_s': time.perf_counter() - t0,
        'targets': {'correct_naming_percent': 95.0, 'false_effects_on_controls': 0,
                    'median_gap_closed': 0.9},
        'rows': rows,
    }
    if baselines:
        from rths_discrepancy import baselines as bl
        summary['baselines'] = bl.summarize(rows)
    summary['targets_met'] = bool(summary['correct_naming_percent'] >= 95.0
                                  and summary['false_effects_on_controls'] == 0
                                  and summary['median_gap_closed'] >= 0.9)
    return summary


def _progress_line(i, n, row):
    mark = 'ok ' if row['correct'] else 'BAD'
    return (f"[{i}/{n}] {mark} {row['scenario']:8s} {row['label']:45s} seed {row['seed']} -> "
            f"{row['named']} (gap closed {row['gap_closed']:.3f}, {row['seconds']:.1f} s)")
