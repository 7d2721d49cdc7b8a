"""``rths bench adaptive``: the designed FIR and the adaptive compensators on a changing plant.

Each scenario drives the simulated plant (Table 1 3-pole actuator, valve #4 DTM, sensor
noise) with one target displacement record (BLWN) through each method, step by step in
closed loop: ``command_k = method.step(target_k, measured_{k-1})``.  The FIR is
designed once on the nominal plant model (the exact ZOH model of the Table 1 3-pole
actuator, standing for a converged identification); every method
starts from that design.  Scenarios (change at mid-run, ``t_c``):

* ``unchanged``: the plant stays as identified;
* ``stiffness_drop``: the specimen's stiffness falls by ``STIFFNESS_DROP`` at ``t_c``: the
  DTM's k_d, and through control-structure interaction the actuator's oil-column/specimen
  mode (the complex pole pair), whose squared frequency falls by the specimen's share
  ``SPECIMEN_SHARE`` of that drop;
* ``plant_drift``: the actuator's gain and bandwidth fall by ``DRIFT`` linearly over
  ``DRIFT_S`` from ``t_c`` (oil warming), retuned every 16th step.

Writes ``DIR/summary.json`` (the issue's layout), ``DIR/config.json`` (scenario definitions,
windows, design, guards' events, load) and one PNG per scenario (error envelope and
coefficients over time, per method).
"""

import json
import os
import sys
import time

import numpy as np

from rths_compensator.methods import adaptive_names, compensator_names

# Imports of the commands' code sit in the command functions: rths imports this module
# to build its parser, and every rths command would pay for SciPy, matplotlib and ROS.

METHOD_NAMES = compensator_names()
SCENARIOS = ('unchanged', 'stiffness_drop', 'plant_drift')
#: The RTHS benchmark's perturbed plants (:mod:`.bench_adaptive_silva`; needs its record).
SILVA = 'silva2020_perturbed'
ALL_SCENARIOS = SCENARIOS + (SILVA,)
STIFFNESS_DROP = 0.3
SPECIMEN_SHARE = 0.5
DRIFT = 0.1
DRIFT_FRACTION_OF_RUN = 0.125       # drift duration / run duration (5 s of 40 s)
FS_HZ = 1024.0
NOISE_M = 2e-6
TARGET_BAND_HZ = 10.0
TARGET_PEAK_M = 5.08e-3
COEF_EVERY = 16
TAPER_S = 1.0


def _log(msg):
    print(msg, file=sys.stderr, flush=True)


def identify_and_design(taps, fs_hz=FS_HZ):
    """Return the nominal plant model (exact ZOH of Table 1's 3-pole model) and its LS FIR.

    A short ARX fit on this simulated plant leaves the high-frequency zeros (one outside the
    unit circle) poorly determined, and the FIR design then fails its passband bound; the
    exact model stands for a converged identification.
    """
    from rths_compensator.design import design_fir
    from rths_compensator.identification import ArxModel
    from rths_compensator.plants import discrete_actuator

    b, a = discrete_actuator('3pole', fs_hz)
    model = ArxModel(a=a, b=b, d=0, fs_hz=fs_hz)
    design = design_fir(model, n_taps=taps, fc_hz=64.0, scheme='ls', zero_tol=0.98)
    return model, design


def _schedule(scenario, n, fs_hz):
    """``{step: retune kwargs}`` of a scenario over ``n`` steps."""
    kc = n // 2
    if scenario == 'unchanged':
        return {}
    if scenario == 'stiffness_drop':
        mode = float(np.sqrt(1.0 - SPECIMEN_SHARE * STIFFNESS_DROP))
        return {kc: {'dtm_stiffness': 1.0 - STIFFNESS_DROP, 'actuator_mode_frequency': mode}}
    if scenario == 'plant_drift':
        steps = max(1, int(round(DRIFT_FRACTION_OF_RUN * n)))
        out = {}
        for k in range(kc, kc + steps + 1, COEF_EVERY):
            s = 1.0 - DRIFT * min(1.0, (k - kc) / steps)
            out[k] = {'actuator_gain': s, 'actuator_bandwidth': s}
        out[kc + steps] = {'actuator_gain': 1.0 - DRIFT, 'actuator_bandwidth': 1.0 - DRIFT}
        return out
    raise ValueError(f'scenario {scenario!r} unknown; use one of {", ".join(SCENARIOS)}')


def run_method(name, scenario, target, model, design, seed, n_correction=16):
    """Closed-loop run of one method in one scenario; return arrays and events."""
    from rths_actuator_bridge.simulated import SimulatedPlant
    from rths_compensator.adaptive import make_method

    options = {'n_correction': n_correction} if name == 'rls_fir' else {}
    method = make_method(name, design, model, **options)
    plant = SimulatedPlant(fs_hz=FS_HZ, displacement_noise_m=NOISE_M, seed=seed + 1)
    schedule = _schedule(scenario, target.size, FS_HZ)
    n = target.size
    measured = np.full(n, np.nan)
    step_ns = np.zeros(n)
    coefs, events = [], []
    state = method.status.state
    prev = None
    clock = time.perf_counter_ns
    for k in range(n):
        change = schedule.get(k)
        if change:
            plant.retune(**change)
        t0 = clock()
        command = method.step(target[k], prev)
        step_ns[k] = clock() - t0
        plant.step(command)
        prev = float(plant.measure()['table_disp'])
        measured[k] = prev
        if k % COEF_EVERY == 0:
            coefs.append(method.coefficients())
        if method.status.state != state and method.status.state == 'fallback':
            events.append({'t_s': k / FS_HZ, 'status': method.status.reason})
        state = method.status.state
        if not np.isfinite(prev) or abs(prev) > 1.0:
            events.append({'t_s': k / FS_HZ, 'status': f'run stopped: measured {prev} m'})
            break
    return {'measured': measured, 'step_ns': step_ns, 'coefficients': np.array(coefs),
            'events': events, 'final_status': [method.status.state, method.status.reason]}


def _window_rms_pct(target, measured, width):
    """Relative RMS error [%] over consecutive windows of ``width`` samples."""
    m = target.size // width
    t = target[:m * width].reshape(m, width)
    e = (measured[:m * width] - target[:m * width]).reshape(m, width)
    return 100 * np.sqrt(np.sum(e ** 2, axis=1) / np.maximum(np.sum(t ** 2, axis=1), 1e-300))


def metrics(target, run):
    """Return the issue's M fields for one run."""
    from rths_compensator.indicators import relative_rms_pct, time_delay_from_data

    y = run['measured']
    n = target.size - int(TAPER_S * FS_HZ)      # the fade-out at the end is left out
    kc = target.size // 2
    before = slice(target.size // 4, kc)
    after = slice(3 * target.size // 4, n)
    finite = bool(np.all(np.isfinite(y)))
    stable = finite and float(np.max(np.abs(y))) <= 2.0 * float(np.max(np.abs(target)))
    out = {'rms_pct_before_change': None, 'rms_pct_after_change': None,
           'delay_ms_after_change': None, 'recovery_s': None, 'stable': stable,
           'step_us_p50': float(np.median(run['step_ns'][:np.count_nonzero(run['step_ns'])])
                                / 1e3)}
    if not finite:
        return out
    e_before = relative_rms_pct(target[before], y[before])
    out['rms_pct_before_change'] = e_before
    out['rms_pct_after_change'] = relative_rms_pct(target[after], y[after])
    out['delay_ms_after_change'] = time_delay_from_data(target[after], y[after], FS_HZ,
                                                        TARGET_BAND_HZ)
    width = int(2 * FS_HZ)
    windows = _window_rms_pct(target[kc:n], y[kc:n], width)
    out['recovery_s'] = recovery_s(windows, 1.2 * e_before, width / FS_HZ)
    return out


def recovery_s(windows, limit, width_s):
    """End time of the first window back within ``limit`` after one above it (0: none above).

    None when the error never comes back within ``limit`` by the end of the run.
    """
    windows = np.asarray(windows, dtype=float)
    above = np.flatnonzero(windows > limit)
    if above.size == 0:
        return 0.0
    back = np.flatnonzero(windows[above[0]:] <= limit)
    if back.size == 0:
        return None
    return float((above[0] + back[0] + 1) * width_s)


def _plot(path, scenario, target, runs):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    adaptive = list(adaptive_names())
    fig, axes = plt.subplots(1 + len(adaptive), 1, figsize=(9, 2.4 * (1 + len(adaptive))),
                             sharex=True)
    width = int(0.5 * FS_HZ)
    t_mid = (np.arange(target.size // width) + 0.5) * width / FS_HZ
    for name in METHOD_NAMES:
        env = _window_rms_pct(target, runs[name]['measured'], width)
        axes[0].semilogy(t_mid, np.maximum(env, 1e-3), label=name)
    axes[0].axvline(target.size / 2 / FS_HZ, color='k', ls=':', lw=1)
    axes[0].set_ylabel('rel. RMS error\nper 0.5 s [%]')
    axes[0].legend(ncol=4, fontsize=8)
    axes[0].set_title(f'{scenario}: error envelope and adapted coefficients')
    for ax, name in zip(axes[1:], adaptive, strict=True):
        c = runs[name]['coefficients']
        t = np.arange(c.shape[0]) * COEF_EVERY / FS_HZ
        c0 = c[0]
        scale = np.where(np.abs(c0) > 0, np.abs(c0), 1.0)
        shown = range(min(c.shape[1], 6))
        for i in shown:
            ax.plot(t, (c[:, i] - c0[i]) / scale[i] * 100, lw=0.8, label=f'c{i}')
        ax.axvline(target.size / 2 / FS_HZ, color='k', ls=':', lw=1)
        ax.set_ylabel(f'{name}\nchange [%]')
        ax.legend(ncol=6, fontsize=7, loc='upper left')
    axes[-1].set_xlabel('time [s]')
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def rls_fir_cost(tap_counts=(32, 200, 400), n_steps=3000):
    """Median/p99 cost [us] of one rls_fir step at ``tap_counts``: every tap vs the correction.

    The FIR (LS, fc 64 Hz) of each length is designed on the bench's plant model; the
    method follows a 3 Hz, 5 mm sine with its own delayed copy as the measurement.
    """
    from rths_compensator.adaptive import RlsFir

    x = 5e-3 * np.sin(2 * np.pi * 3.0 * np.arange(n_steps + 500) / FS_HZ)
    out = {}
    clock = time.perf_counter_ns
    for taps in tap_counts:
        model, design = identify_and_design(taps)
        for label, options in (('every_tap', {'n_full': 10 ** 9}), ('correction', {})):
            if label == 'correction' and taps <= 32:
                continue
            method = RlsFir(design, model, **options)
            ts = np.empty(x.size)
            for k in range(x.size):
                t0 = clock()
                method.step(x[k], x[k - 1] if k else None)
                ts[k] = clock() - t0
            ts = ts[500:] / 1e3
            out[f'{taps}_taps_{label}'] = {'p50_us': round(float(np.median(ts)), 1),
                                           'p99_us': round(float(np.percentile(ts, 99)), 1)}
    return out


def _floor_us(repeats=20000):
    """Median cost of an empty Python call on this machine now [us] (timing floor)."""
    def empty(a, b):
        return a
    clock = time.perf_counter_ns
    ts = np.empty(repeats)
    for i in range(repeats):
        t0 = clock()
        empty(0.0, 0.0)
        ts[i] = clock() - t0
    return float(np.median(ts) / 1e3)


def run_bench(out_dir, duration_s=40.0, seed=14, taps=32, scenarios=SCENARIOS, plots=True,
              n_correction=16, silva=None):
    """Run every method in every scenario; write the files; return the summary dict.

    ``silva``: keyword arguments of :func:`.bench_adaptive_silva.run_scenario` (record,
    n_draws, seed, duration_s, data_dir, cases, fir_options) for ``silva2020_perturbed``.
    """
    from rths_numerical.signals import blwn

    if duration_s < 8.0:
        raise ValueError(f'--duration {duration_s} s is too short; use >= 8 s (the metrics '
                         'use 2 s windows after the mid-run change)')
    os.makedirs(out_dir, exist_ok=True)
    model, design = identify_and_design(taps)
    _log(f'plant model: ZOH of Table 1 3-pole; FIR LS n={taps} fc=64 Hz: {design.taps.size} taps, '
         f'denominator {design.denominator.size} coefficients')
    target = blwn(duration_s, FS_HZ, TARGET_BAND_HZ, TARGET_PEAK_M,
                  np.random.default_rng(seed + 100), taper_s=TAPER_S)
    unknown = [s for s in scenarios if s not in ALL_SCENARIOS]
    if unknown:
        raise ValueError(f'scenario {unknown[0]!r} unknown; use {", ".join(ALL_SCENARIOS)}')
    from rths_common.progress import Progress

    simulated = [s for s in scenarios if s in SCENARIOS]
    summary, events = {'scenarios': {}}, {}
    bar = Progress(len(simulated) * len(METHOD_NAMES), 'bench adaptive', 'runs')
    for scenario in simulated:
        runs, block = {}, {}
        for name in METHOD_NAMES:
            t0 = time.perf_counter()
            runs[name] = run_method(name, scenario, target, model, design, seed, n_correction)
            block[name] = metrics(target, runs[name])
            events[f'{scenario}/{name}'] = {'events': runs[name]['events'],
                                            'final_status': runs[name]['final_status']}
            m = block[name]
            with bar.hidden():
                _log(f'{scenario:15s} {name:8s} before {_fmt(m["rms_pct_before_change"])} % '
                     f'after {_fmt(m["rms_pct_after_change"])} % delay '
                     f'{_fmt(m["delay_ms_after_change"])} ms recovery {m["recovery_s"]} s '
                     f'stable {m["stable"]} step {m["step_us_p50"]:.1f} us '
                     f'({time.perf_counter() - t0:.1f} s)')
            bar.advance()
        summary['scenarios'][scenario] = block
        if plots:
            _plot(os.path.join(out_dir, f'{scenario}.png'), scenario, target, runs)
    bar.close()
    config = _config(duration_s, seed, taps, model, design, events)
    if SCENARIOS[0] in scenarios:
        config['rls_fir_step_cost'] = rls_fir_cost()
        _log('rls_fir step cost [us] (p50/p99): ' + ', '.join(
            f'{k} {v["p50_us"]}/{v["p99_us"]}' for k, v in config['rls_fir_step_cost'].items()))
    config['design']['rls_fir'] = ('all n taps adapt' if taps <= 32 else
                                   f'a correction of {n_correction} taps adapts')
    if SILVA in scenarios:
        summary['scenarios'][SILVA], config[SILVA] = _run_silva(out_dir, n_correction, silva,
                                                                plots)
    with open(os.path.join(out_dir, 'summary.json'), 'w', encoding='utf-8') as handle:
        json.dump(summary, handle, indent=2)
    with open(os.path.join(out_dir, 'config.json'), 'w', encoding='utf-8') as handle:
        json.dump(config, handle, indent=2)
    return summary


def _run_silva(out_dir, n_correction, options, plots):
    """Run ``silva2020_perturbed``: ``(summary block, config entry)``."""
    from . import bench_adaptive_silva as silva
    options = dict(options or {})
    blocks, details, per_run = silva.run_scenario(options={'n_correction': n_correction},
                                                  log=_log, **options)
    n_cases = len(details['cases'])
    if plots:
        silva.plot(os.path.join(out_dir, f'{SILVA}.png'), blocks, per_run, n_cases)
    details['definition'] = (
        'the RTHS benchmark (Silva et al. 2020; rths bench rths-benchmark): its loop, timing '
        'and converters, its FIR procedure (BLWN test, ARX grid, design against a 400 Hz '
        'target low-pass), the nominal plant of each case and the perturbed plants of case '
        '1 (draws of the benchmark seed); every method as the controller, one object per run')
    details['metrics'] = {
        'J1_ms': "the benchmark's J1: lag of best correlation of x_m with y_n (0.1 ms)",
        'J2_pct': "the benchmark's J2: RMS tracking error of x_m vs y_n, % (std ratio)",
        'J3_pct': "the benchmark's J3: peak tracking error, %",
        'delay_ms': 'eq. 42 delay of x_m vs y_n (H1 FRF, 0-10 Hz); worst = largest |delay|',
        'stable': 'count of perturbed plants with x_m finite, within 10 x the reference '
                  'floor-1 peak and max |x_m| <= 2 max |y_n|',
        'fallbacks': 'count of perturbed plants on which the method fell back to the FIR',
        'median/worst': 'over the perturbed plants (worst = largest)',
        'vs_fir': "ratios of the method's J2 median/worst to fir's",
        'nominal': 'J1-J3 of the nominal plant of each case',
        'step_us_p50': 'median wall time of method.step over every step of every run'}
    details['per_run'] = per_run
    details['load_average'] = list(os.getloadavg())
    return blocks, details


def _fmt(value):
    return 'n/a' if value is None else f'{value:.3f}'


def _config(duration_s, seed, taps, model, design, events):
    from rths_compensator.adaptive import Guards
    n = int(round(duration_s * FS_HZ))
    return {
        'fs_hz': FS_HZ, 'duration_s': duration_s, 'seed': seed,
        'target': f'BLWN 0-{TARGET_BAND_HZ:g} Hz, peak {TARGET_PEAK_M * 1e3:g} mm, 1 s tapers',
        'plant': 'SimulatedPlant: Table 1 3-pole actuator, valve4 DTM, displacement noise '
                 f'{NOISE_M:g} m std',
        'identified_plant': {'model': 'ZOH of the Table 1 3-pole model at fs_hz (d = 0), '
                                      'standing for a converged identification',
                             'a': model.a.tolist(), 'b': model.b.tolist()},
        'design': {'scheme': 'ls', 'n_taps': taps, 'fc_hz': 64.0, 'zero_tol': 0.98,
                   'taps': design.taps.size, 'denominator': design.denominator.tolist()},
        'change_s': (n // 2) / FS_HZ,
        'windows_s': {'before_change': [(n // 4) / FS_HZ, (n // 2) / FS_HZ],
                      'after_change': [(3 * n // 4) / FS_HZ, n / FS_HZ - TAPER_S]},
        'scenarios': {
            'unchanged': 'no change',
            'stiffness_drop': f'at change_s the specimen stiffness falls by '
                              f'{STIFFNESS_DROP:.0%}: DTM k_d x {1 - STIFFNESS_DROP:g}; the '
                              f'actuator\'s complex pole pair (oil column + specimen, '
                              f'specimen share {SPECIMEN_SHARE:g}) frequency x '
                              f'sqrt(1 - {SPECIMEN_SHARE:g} x {STIFFNESS_DROP:g})',
            'plant_drift': f'from change_s the actuator gain and bandwidth (all poles) fall '
                           f'linearly by {DRIFT:.0%} over {DRIFT_FRACTION_OF_RUN * duration_s:g}'
                           f' s, retuned every {COEF_EVERY} steps, then stay'},
        'metrics': {
            'rms_pct': 'eq. 43 relative RMS error of measured vs target over the window',
            'delay_ms_after_change': 'eq. 42 delay (H1 FRF, 0-10 Hz) over the after window',
            'recovery_s': 'end of the first 2 s window after the change whose error is '
                          'back <= 1.2 x the before-change error, after one above it; 0 = '
                          'never above; null = not back by the end of the run (the last '
                          f'{TAPER_S:g} s, the target fading out, left out)',
            'stable': 'measured finite and max |measured| <= 2 x max |target|',
            'step_us_p50': 'median wall time of method.step (perf_counter_ns)'},
        'guards': vars(Guards()),
        'events': events,
        'load_average': list(os.getloadavg()),
        'floor_empty_call_us_p50': _floor_us(),
    }


def _scenarios(args):
    """Return the requested scenarios.

    The benchmark's is left out by default when its record is absent; named explicitly,
    a missing record is an error.
    """
    if args.scenarios:
        return tuple(s.strip() for s in args.scenarios.split(',') if s.strip())
    from .rths_benchmark import record_path
    try:
        record_path(args.record, args.data_dir)
    except OSError as exc:
        _log(f'{SILVA} skipped: {exc}')
        return SCENARIOS
    return ALL_SCENARIOS


def _cmd_bench(args):
    t0 = time.perf_counter()
    if args.step_cost:
        from .bench_step_cost import run_step_cost
        rates = tuple(int(float(r)) for r in args.step_cost_rates.split(',') if r.strip())
        out = run_step_cost(args.out, duration_s=args.step_cost_s, rates=rates)
        _log(f'wrote {args.out}/summary.json in {time.perf_counter() - t0:.0f} s')
        print(json.dumps({rate: {name: {k: row[k] for k in ('step_us_p50', 'step_us_p99',
                                                            'core_step_us_p50',
                                                            'core_step_us_p99')}
                                 for name, row in block['methods'].items()}
                          for rate, block in out['rates'].items()}, indent=2))
        return 0
    silva = {'record': args.record, 'data_dir': args.data_dir, 'n_draws': args.draws,
             'duration_s': args.benchmark_duration or None}
    summary = run_bench(args.out, duration_s=args.duration, seed=args.seed, taps=args.taps,
                        plots=not args.no_plots, n_correction=args.n_correction,
                        scenarios=_scenarios(args), silva=silva)
    _log(f'wrote {args.out}/summary.json in {time.perf_counter() - t0:.0f} s')
    print(json.dumps(summary, indent=2))
    return 0


def register(commands, benches):
    """Add ``rths bench adaptive``."""
    p = benches.add_parser(
        'adaptive', help='designed FIR vs RLS-adaptive FIR, ATS and AMB on a changing plant',
        description='Design the FIR on the simulated plant, then run fir, rls_fir, ats '
                    'and amb in closed loop through three scenarios (unchanged, '
                    'stiffness_drop, plant_drift; the change at mid-run; about 1 min), and '
                    'on the RTHS benchmark (Silva et al. 2020): the nominal plant of each case '
                    'and the 20 perturbed plants (silva2020_perturbed; its record from '
                    '$RTHS_DATA_DIR or --data-dir, left out with a message when absent; '
                    'about 10-20 min). Writes DIR/summary.json ({"scenarios": {SCENARIO: '
                    '{METHOD: {...}}}}), DIR/config.json (definitions, windows, events, '
                    'load, per-run results) and one PNG per scenario (error envelope and '
                    'coefficients over time; J1/J2 per perturbed plant).')
    p.add_argument('--out', required=True, help='output directory')
    p.add_argument('--duration', type=float, default=40.0,
                   help='run length [s] (default 40; the change is at mid-run)')
    p.add_argument('--seed', type=int, default=14, help='seed of target, noise, '
                   'identification (default 14)')
    p.add_argument('--taps', type=int, default=32, help='FIR length n of H (default 32)')
    p.add_argument('--n-correction', type=int, default=16,
                   help='rls_fir: taps of the correction C (H = H0 (1 + C)) that it adapts '
                        'when H has more than 32 taps (default 16; the cost per step grows '
                        'as n + n_correction^2)')
    p.add_argument('--scenarios', default='',
                   help=f'comma-separated subset of {",".join(ALL_SCENARIOS)} (default all; '
                        f'{SILVA} only when its record is found)')
    p.add_argument('--record', default='elcentro',
                   help=f'{SILVA}: benchmark record (elcentro, kobe, morganhill, or a file '
                        'path; default elcentro)')
    p.add_argument('--data-dir', default=None,
                   help=f'{SILVA}: directory of the records (default $RTHS_DATA_DIR)')
    p.add_argument('--draws', type=int, default=20,
                   help=f'{SILVA}: perturbed plants of case 1 (default 20, seed 2020)')
    p.add_argument('--benchmark-duration', type=float, default=0.0,
                   help=f'{SILVA}: shorten the record [s] (default 0: all of it)')
    p.add_argument('--no-plots', action='store_true', help='skip the PNG files')
    p.add_argument('--step-cost', action='store_true',
                   help='instead of the scenarios: time the step of every method (method.step '
                        "and the node core's step) at 1024 Hz (config/compensator.yaml, "
                        '400 taps) and 4096 Hz (the RTHS benchmark\'s graph design, 200 taps) '
                        'in closed loop on the plant model; writes DIR/summary.json ({"rates": '
                        '{RATE: {"methods": {METHOD: {step_us_p50, step_us_p99, '
                        'core_step_us_p50, core_step_us_p99, states}}}}}, load average; about '
                        '1-2 min)')
    p.add_argument('--step-cost-s', type=float, default=8.0,
                   help='--step-cost: timed run length per method and rate [s] (default 8)')
    p.add_argument('--step-cost-rates', default='1024,4096',
                   help='--step-cost: comma-separated rates [Hz] of 1024,4096 (default both)')
    p.set_defaults(func=_cmd_bench)
