"""``rths bench adaptive``'s ``silva2020_perturbed`` scenario: every method on the benchmark.

The RTHS benchmark control problem (Silva et al. 2020, :mod:`.rths_benchmark`) with the
adaptive methods as its controller: the same vectorised loop (:func:`.rths_benchmark.run_batch`,
the benchmark's timing and converters), the same lab procedure for the designed FIR
(:func:`.rths_benchmark.identify_and_design`: BLWN test, ARX grid, FIR design against a
target low-pass), the same plants (the four cases with the nominal plant, and the
perturbed plants of case 1 drawn with the benchmark's seed).  Each method runs one
:mod:`rths_compensator.adaptive` object per run of the batch:
``u(k) = D/A(method.step(y_n(k), A/D(x_m(k))))``, where x_m(k) answers u(k-1).

What each method starts from: ``fir`` and ``rls_fir`` from the designed FIR and the plant
it was designed on (the identified ARX model over the target low-pass); ``ats`` and
``amb`` from the identified ARX model (their low-order bases need no low-pass).
"""

import time

import numpy as np

from rths_compensator.methods import compensator_names

from . import rths_benchmark as rb

# Imports of the commands' code sit in the command functions: rths imports this module
# to build its parser, and every rths command would pay for SciPy, matplotlib and ROS.

METHOD_NAMES = compensator_names()
NAME = 'silva2020_perturbed'
#: Band of the delay estimate (eq. 42) [Hz]: the records' energy lies below it.
DELAY_BAND_HZ = 10.0


def run_method(name, runs, ag, design, plants, seed, options=None):
    """Run method ``name`` on every ``(case, params)`` of ``runs``; return the batch output."""
    design_plant, identified = plants
    plant = design_plant if name == 'rls_fir' else identified
    from rths_common.progress import Progress
    ctrl = rb.MethodController(name, design, plant, len(runs), options)
    with Progress(len(ag), f'{NAME} {name} ({len(runs)} loops)', 'steps') as bar:
        out = rb.run_batch(runs, ag, ctrl, seed=seed, progress=bar.report)
    out['step_ns'] = np.asarray(ctrl.step_ns, float)
    out['events'] = ctrl.events
    out['final_status'] = [[m.status.state, m.status.reason] for m in ctrl.methods]
    return out


def run_metrics(x_m, y_n, ref, dt):
    """J1-J3, the eq. 42 delay and stability of one run (None where not finite)."""
    from rths_compensator.indicators import time_delay_from_data
    finite = bool(np.all(np.isfinite(x_m)))
    stable = finite and not rb.unstable(x_m, ref) \
        and float(np.max(np.abs(x_m))) <= 2.0 * float(np.max(np.abs(y_n[:, 0])))
    if not finite:
        return {'J1': None, 'J2': None, 'J3': None, 'delay_ms': None, 'stable': False}
    js = rb.criteria(x_m, y_n, ref, dt)
    delay = time_delay_from_data(y_n[:, 0], x_m, 1.0 / dt, DELAY_BAND_HZ)
    return {'J1': js['J1'], 'J2': js['J2'], 'J3': js['J3'], 'delay_ms': round(delay, 4),
            'stable': stable}


def _spread(values, worst=max):
    vals = [v for v in values if v is not None]
    if not vals:
        return {'median': None, 'worst': None}
    return {'median': round(float(np.median(vals)), 4), 'worst': round(float(worst(vals)), 4)}


def aggregate(per_run, n_cases, step_ns, events):
    """Per-method block: nominal cases, and median/worst over the perturbed plants."""
    perturbed = per_run[n_cases:]
    block = {
        'n': len(perturbed),
        'stable': int(sum(r['stable'] for r in perturbed)),
        'fallbacks': int(sum(bool(e) for e in events[n_cases:])),
        'J1_ms': _spread([r['J1'] for r in perturbed]),
        'J2_pct': _spread([r['J2'] for r in perturbed]),
        'J3_pct': _spread([r['J3'] for r in perturbed]),
        'delay_ms': _spread([r['delay_ms'] for r in perturbed], worst=lambda v: max(v, key=abs)),
        'step_us_p50': round(float(np.median(step_ns)) / 1e3, 3) if step_ns.size else None,
    }
    return block


def compare_with_fir(blocks):
    """Add ``vs_fir`` (ratios of J2 median and worst to fir's) to every other method."""
    fir = blocks.get('fir')
    if not fir:
        return blocks
    for name, block in blocks.items():
        if name == 'fir':
            continue
        ratios = {}
        for key in ('median', 'worst'):
            ours, ref = block['J2_pct'][key], fir['J2_pct'][key]
            ratios[f'J2_{key}_ratio'] = None if ours is None or not ref \
                else round(ours / ref, 4)
        block['vs_fir'] = ratios
    return blocks


def run_scenario(record='elcentro', n_draws=20, seed=2020, duration_s=None, data_dir=None,
                 cases=rb.CASES, fir_options=None, methods=METHOD_NAMES, options=None,
                 log=rb._log):
    """Run every method on the nominal cases and ``n_draws`` perturbed plants of case 1.

    Returns ``(blocks, details, per_run)``: ``blocks[method]`` the summary block,
    ``details`` the settings for config.json, ``per_run[method]`` J1-J3/delay/stable of
    each run (cases first, then the draws), guard events and final statuses.
    """
    from rths_actuator_bridge.silva2020 import FS_HZ, Silva2020Params, perturbed
    dt = 1.0 / FS_HZ
    t0 = time.perf_counter()
    t, ag = rb.ground_acceleration(record, FS_HZ, data_dir=data_dir, duration_s=duration_s)
    rng = np.random.default_rng(seed)
    draws = [perturbed(rng) for _ in range(n_draws)]
    runs = [(c, Silva2020Params()) for c in cases] + [('1', p) for p in draws]
    log(f'{NAME}: record {record} ({t[-1]:.2f} s, {len(t)} steps at {FS_HZ:g} Hz), '
        f'{len(cases)} nominal cases + {n_draws} perturbed plants (seed {seed})')
    design, info = rb.identify_and_design(log=log, **(fir_options or {}))
    plants = rb.plants_of(info, FS_HZ)
    refs = {c: rb.reference_response(c, ag, dt) for c in set(c for c, _ in runs)}
    blocks, per_run = {}, {}
    for name in methods:
        t1 = time.perf_counter()
        out = run_method(name, runs, ag, design, plants, seed,
                         (options or {}) if name == 'rls_fir' else None)
        rows = [run_metrics(out['x_m'][i], out['y_n'][i], refs[c], dt)
                for i, (c, _) in enumerate(runs)]
        block = aggregate(rows, len(cases), out['step_ns'], out['events'])
        block['nominal'] = {c: {k: rows[i][k] for k in ('J1', 'J2', 'J3', 'stable')}
                            for i, c in enumerate(cases)}
        blocks[name] = block
        per_run[name] = {'runs': rows, 'events': out['events'],
                         'final_status': out['final_status']}
        log(f'{NAME:15s} {name:8s} stable {block["stable"]}/{block["n"]} J2 median '
            f'{block["J2_pct"]["median"]} % worst {block["J2_pct"]["worst"]} %, J1 worst '
            f'{block["J1_ms"]["worst"]} ms, step {block["step_us_p50"]} us '
            f'({time.perf_counter() - t1:.0f} s)')
    compare_with_fir(blocks)
    details = {'record': record, 'scale': rb.RECORDS.get(record, (None, 1.0))[1],
               'duration_s': float(t[-1]), 'fs_hz': FS_HZ, 'seed': seed,
               'cases': list(cases), 'n_draws': n_draws,
               'draws': [{k: round(float(getattr(p, k)), 6) for k in ('b1', 'b2', 'a3', 'k_e')}
                         for p in draws],
               'fir_design': info, 'rls_fir_options': options or {},
               'total_s': round(time.perf_counter() - t0, 1)}
    return blocks, details, per_run


def plot(path, blocks, per_run, n_cases):
    """J2 and J1 of every perturbed plant, per method (fir's as the reference line)."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True)
    for name in blocks:
        rows = per_run[name]['runs'][n_cases:]
        x = np.arange(1, len(rows) + 1)
        for ax, key in zip(axes, ('J2', 'J1'), strict=True):
            vals = [np.nan if r[key] is None else r[key] for r in rows]
            ax.plot(x, vals, 'o-' if name == 'fir' else 'o', ms=4, lw=0.8, label=name)
    axes[0].set_ylabel('J2: RMS tracking\nerror [%]')
    axes[1].set_ylabel('J1: delay [ms]')
    axes[1].set_xlabel('perturbed plant (case 1, benchmark draw)')
    axes[1].xaxis.get_major_locator().set_params(integer=True)
    axes[0].legend(ncol=4, fontsize=8)
    axes[0].set_title(f'{NAME}: every method on the benchmark\'s perturbed plants')
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
