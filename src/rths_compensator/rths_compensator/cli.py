"""Sub-commands this package adds to the ``rths`` command (see rths_bringup.cli).

* ``rths identify``        ARX identification + model selection -> plant.yaml
* ``rths design``          compensator design -> ROS 2 parameters file (or ``--auto``)
* ``rths compensate``      apply a designed compensator offline to a CSV command
* ``rths unstable-zeros``  Appendix I: sampling-frequency threshold of the unstable zero
* ``rths bench compensators``  the seed's numerical study (section 4.3.3) -> JSON (+ plots)
"""

import os
import sys

from rths_common.columns import read_columns

from .schemes import SCHEMES, designed

# Imports of the commands' code sit in the command functions: rths imports this module
# to build its parser, and every rths command would pay for SciPy, matplotlib and ROS.

#: What a design reports beside its options, kept in the provenance.
DESIGN_RESULTS = ('a_tilde', 'model', 'q', 'solver', 'auto_score', 'bandwidth_hz')
#: Design option -> the ``rths design`` argument that gives it (``--option KEY=VALUE`` gives
#: any other option a scheme names).
OPTION_ARGS = {'n_taps': 'taps', 'fc_hz': 'fc', 'epsilon': 'epsilon', 'zero_tol': 'zero_tol',
               'alpha': 'alpha', 'poles': 'mff_model', 'delay_ms': 'delay_ms', 'band_hz': 'band'}


def _log(msg):
    print(msg, file=sys.stderr, flush=True)


def register(commands, benches):
    """Add this package's ``rths <command>`` and ``rths bench <name>`` parsers."""
    p = commands.add_parser(
        'identify', help='identify the actuator plant (ARX grid + BIC selection) -> plant.yaml',
        description='Fit ARX models na, nb = 1..29 (eq. 26-27, least squares) to a recorded '
                    'identification run, score them on validation records by MSE/FIT/AIC/BIC '
                    '(eq. 37-40) and write the most frequent winner of --criterion to --out. '
                    'The run (CSV columns time [s], command [m], measured [m]; sampling rate '
                    'read from time) is cut into --record-s records; the first third trains, '
                    'the rest validates (or give --val-csv). Prints the selection summary.')
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument('--csv', help='identification run as CSV (time, command, measured)')
    src.add_argument('--bag', help='identification run as a rosbag2 bag directory')
    p.add_argument('--val-csv', help='separate validation run (CSV); default: split --csv')
    p.add_argument('--out', required=True, help='plant file to write (YAML)')
    p.add_argument('--record-s', type=float, default=10.0, help='record length [s] (10)')
    p.add_argument('--na-max', type=int, default=29, help='largest na (29)')
    p.add_argument('--nb-max', type=int, default=29, help='largest nb (29)')
    p.add_argument('--d-max', type=int, default=0, help='largest dead time d [samples] (0)')
    p.add_argument('--criterion', default='bic', choices=('mse', 'fit', 'aic', 'bic'),
                   help='selection criterion (bic, as the seed)')
    p.add_argument('--error', default='simulation', choices=('simulation', 'prediction'),
                   help='validation error: simulated output (default) or one-step prediction')
    p.set_defaults(func=cmd_identify)

    p = commands.add_parser(
        'design', help='design a delay compensator from plant.yaml -> ROS 2 parameters file',
        description='Design a compensator scheme for the plant and write the compensator node '
                    'parameters (taps, denominator, provenance, predicted delay and gain '
                    'error). Refuses (exit 2, nothing written) unstable, non-finite or '
                    'constraint-violating designs. With --auto --bandwidth HZ it searches '
                    'scheme, n and fc and explains its choice. Schemes: '
                    + '; '.join(f'{n}: {s.summary}' for n, s in SCHEMES.items() if s.designer))
    p.add_argument('--plant', required=True,
                   help='plant file from rths identify, or the updated_model.yaml of rths '
                        'discrepancy --scenario actuator (its time_delay and linear loop '
                        'loads folded into the ARX; other effects refused)')
    p.add_argument('--scheme', choices=designed(), help='compensator scheme')
    p.add_argument('--taps', type=int, default=100, help='FIR length n of H (100)')
    p.add_argument('--fc', type=float, default=64.0, help='FIR passband edge fc [Hz] (64)')
    p.add_argument('--epsilon', type=float, default=None,
                   help='FIR passband tolerance on |T_com - 1| (0.002)')
    p.add_argument('--zero-tol', type=float, default=None,
                   help='FIR (also --auto): zeros of the plant numerator with modulus >= this '
                        'count as unstable (B-*, eq. 7) and are not cancelled by the '
                        'denominator B+*; below 1 it keeps lightly damped zeros out of it '
                        '(1; rths bench compensators uses 0.98)')
    p.add_argument('--alpha', type=float, default=7.0, help='mff: alpha of eq. 4 (7)')
    p.add_argument('--mff-model', default='3pole', choices=('3pole', '4pole'),
                   help='mff: Table 1 continuous-time model (3pole)')
    p.add_argument('--delay-ms', type=float, default=None,
                   help='inverse: actuator delay [ms] (default: from the plant over --band)')
    p.add_argument('--band', type=float, default=20.0,
                   help='band [Hz] for the predicted indicators of non-FIR schemes (20)')
    p.add_argument('--option', action='append', default=[], metavar='KEY=VALUE',
                   help='a design option of the scheme that has no flag of its own (repeatable)')
    p.add_argument('--auto', action='store_true', help='search scheme, n, fc (needs --bandwidth)')
    p.add_argument('--bandwidth', type=float, help='operating bandwidth [Hz] for --auto')
    p.add_argument('--out', required=True, help='parameters file to write (YAML)')
    p.set_defaults(func=cmd_design)

    p = commands.add_parser(
        'compensate', help='apply a compensator parameters file offline to a CSV command',
        description='Filter the command column of --csv causally, sample by sample, with the '
                    'compensator of --params (the same filter class the node uses) and write '
                    'time, command, compensated to --out.')
    p.add_argument('--params', required=True, help='compensator parameters file')
    p.add_argument('--csv', required=True, help='input CSV with columns time [s], command [m]')
    p.add_argument('--out', required=True, help='output CSV (time, command, compensated)')
    p.set_defaults(func=cmd_compensate)

    p = commands.add_parser(
        'unstable-zeros', help='Appendix I: sampling rate above which the ZOH plant is '
                               'non-minimum phase',
        description='Discretise the Table 1 3-pole and 4-pole models by ZOH over a range of '
                    'sampling frequencies, print the frequency at which a zero leaves the '
                    'unit circle (seed: ~41 Hz and ~42 Hz) and optionally plot |zeros| vs fs.')
    p.add_argument('--plot', help='PNG file of |zeros| vs sampling frequency')
    p.add_argument('--fs-max', type=float, default=1024.0, help='largest fs for the plot (1024)')
    p.set_defaults(func=cmd_unstable_zeros)

    p = benches.add_parser(
        'compensators', help="the seed's numerical compensator study (section 4.3.3)",
        description='Identify the ARX plant from noisy simulated BLWN runs of the 3-pole model, '
                    'design the 72 FIR compensators and the comparison compensators, evaluate '
                    'them on the plant under BLWN 0-5/10/20/30 Hz (5.08 mm peak), time the '
                    'node filter step, print the targets and write JSON (and PNG figures).')
    p.add_argument('--out', required=True, help='JSON result file')
    p.add_argument('--plots', help='directory for PNG figures (Figures 5-10)')
    p.add_argument('--seed', type=int, default=2024, help='random seed (2024)')
    p.add_argument('--noise-m', type=float, default=2e-6,
                   help='measurement noise std [m] (2e-6)')
    p.add_argument('--eval-s', type=float, default=60.0, help='evaluation BLWN length [s] (60)')
    p.add_argument('--epsilon', type=float, default=None,
                   help='FIR passband tolerance (0.002)')
    p.set_defaults(func=cmd_bench_compensators)


def _read_run(args, path):
    from rths_common.timebase import infer_rate

    cols = read_columns(path, ('time', 'command', 'measured'))
    rate = infer_rate(cols['time'], path)
    _log(f'{path}: sampling rate {rate}')
    return cols['time'], cols['command'], cols['measured'], rate.fs_hz


def cmd_identify(args) -> int:
    """``rths identify``."""
    from rths_common.bagio import read_identification
    from rths_common.timebase import format_hz, same_rate, sampling_rate_hz

    from ._blas import limit_blas_threads
    from .identification import identify, save_plant, split_records
    limit_blas_threads(1)
    if args.bag:
        t, u, y = read_identification(args.bag)
        fs = sampling_rate_hz(t, args.bag)
    else:
        t, u, y, fs = _read_run(args, args.csv)
    from .causality import check_causality
    lag = check_causality(u, y, fs, str(args.bag or args.csv))
    _log(f'identify: the measured signal lags the command by {lag * 1e3:.2f} ms')
    records = split_records(t, u, y, args.record_s)
    if args.val_csv:
        tv, uv, yv, fsv = _read_run(args, args.val_csv)
        check_causality(uv, yv, fsv, args.val_csv)
        if not same_rate(fsv, fs):
            raise ValueError(f'{args.val_csv}: sampling rate {format_hz(fsv)} Hz differs '
                             f'from {format_hz(fs)} Hz of the identification run; record '
                             'both at one rate')
        train, val = records, split_records(tv, uv, yv, args.record_s)
    else:
        k = max(1, len(records) // 3)
        train, val = records[:k], records[k:]
    _log(f'identify: fs = {format_hz(fs)} Hz, {len(train)} training and {len(val)} validation '
         f'records of {args.record_s} s; grid {args.na_max} x {args.nb_max} x {args.d_max + 1}')
    from rths_common.progress import Progress

    with Progress(0, 'identify: ARX models') as bar:
        model, info, _ = identify(train, val, fs, args.na_max, args.nb_max, args.d_max,
                                  args.criterion, args.error, progress=bar.report)
        bar.update(bar.total)                         # (the grid reports every 100 models)
    info['source'] = str(args.bag or args.csv)
    save_plant(args.out, model, info)
    print(f'selected ({args.criterion}): na={model.na} nb={model.nb} d={model.d}, '
          f'stable={model.is_stable()}, DC gain {model.dc_gain():.4f}')
    for crit in ('mse', 'fit', 'aic', 'bic'):
        print(f'  {crit}: ' + '; '.join(info[crit]['top'][:3]))
    print(f'wrote {args.out}')
    return 0


def cmd_design(args) -> int:
    """``rths design``."""
    import numpy as np

    from . import design as dsg
    from ._blas import limit_blas_threads
    from .identification import load_plant
    from .params import write_compensator_params
    limit_blas_threads(1)
    plant = load_plant(args.plant)
    _snap_plant_rate(plant, args.plant)
    eps = dsg.DEFAULT_EPSILON if args.epsilon is None else args.epsilon
    zero_tol = 1.0 if args.zero_tol is None else args.zero_tol
    if not 0 < zero_tol <= 1:
        raise ValueError(f'--zero-tol must lie in (0, 1], got {zero_tol}')
    if (args.zero_tol is not None and not args.auto and args.scheme
            and not SCHEMES.entry(args.scheme).fir):
        raise ValueError(f'--zero-tol applies to the FIR schemes ({", ".join(dsg.FIR_SCHEMES)}) '
                         f'and --auto, not to --scheme {args.scheme}; drop it')
    if args.auto:
        if not args.bandwidth:
            raise ValueError('--auto needs --bandwidth HZ (the operating bandwidth)')
        _log(f'design --auto: searching for 0-{args.bandwidth} Hz')
        from rths_common.progress import Progress

        with Progress(0, 'design --auto', 'candidates') as bar:
            comp, table = dsg.auto_design(plant, args.bandwidth, epsilon=eps,
                                          zero_tol=zero_tol, progress=bar.report)
        band = args.bandwidth
        print('score = |delay| [ms] + gain error [dB] + 0.1 x max(0, high-pass gain above the '
              'band - 6 dB) + 1e-4 x coefficients (lower is better); top candidates:')
        for row in table[:8]:
            if row['error']:
                continue
            print(f"  {row['scheme']:6s} n={row['n_taps']!s:>4} fc={row['fc_hz']!s:>6} "
                  f"score {row['score']:.3f}: delay {row['delay_ms']:+.3f} ms, gain error "
                  f"{row['gain_error_db']:.3f} dB, high-pass {row['highpass_gain_db']:.1f} dB, "
                  f"{row['n_coefficients']} coefficients")
        top = table[0]
        print(f"chose {top['scheme']} n={top['n_taps']} fc={top['fc_hz']}: lowest score; its "
              f"predicted delay over 0-{band} Hz is {top['delay_ms']:+.3f} ms and gain error "
              f"{top['gain_error_db']:.3f} dB")
    else:
        if not args.scheme:
            raise ValueError(f'give --scheme ({", ".join(designed())}) or --auto --bandwidth HZ')
        scheme = SCHEMES.entry(args.scheme, '--scheme')
        if scheme.fir:
            from .params import check_filter_cost
            check_filter_cost(args.taps, plant.fs_hz, f'--taps {args.taps}')
        given = dict(vars(args), epsilon=eps, zero_tol=zero_tol)
        opts = {key: given[OPTION_ARGS[key]] for key in scheme.options if key in OPTION_ARGS}
        opts.update(_options(args.option, scheme.options))
        band = args.fc if scheme.fir else args.band
        comp = dsg.design(plant, args.scheme, **opts)
    pred = dsg.predict(plant, comp, band)
    if not all(np.isfinite(v) for v in pred.values()):
        raise ValueError(f'{comp.scheme} design has non-finite predicted indicators; refused')
    prov = {'plant': os.path.abspath(args.plant), 'n_coefficients': int(comp.taps.size),
            'predicted_band_hz': float(band),
            'predicted_delay_ms': pred['delay_ms'],
            'predicted_gain_error_db': pred['gain_error_db'],
            'predicted_highpass_gain_db': pred['highpass_gain_db']}
    for key in SCHEMES.entry(comp.scheme).options + DESIGN_RESULTS:
        if key in comp.info:
            prov[key] = comp.info[key]
    write_compensator_params(args.out, comp.taps, comp.denominator, comp.fs_hz, comp.scheme,
                             prov)
    print(f'{comp.scheme}: {comp.taps.size} taps, denominator order '
          f'{comp.denominator.size - 1}; predicted over 0-{band:g} Hz: delay '
          f'{pred["delay_ms"]:+.3f} ms, gain error {pred["gain_error_db"]:.3f} dB, '
          f'high-pass gain above {pred["highpass_gain_db"]:.1f} dB')
    print(f'wrote {args.out}')
    return 0


def _options(pairs, allowed) -> dict:
    """``--option KEY=VALUE`` pairs as a dict (numbers as floats); refuse keys not ``allowed``."""
    out = {}
    for pair in pairs:
        key, sep, value = pair.partition('=')
        if not sep or key not in allowed:
            raise ValueError(f'--option {pair}: give KEY=VALUE with KEY one of '
                             f'{", ".join(allowed) or "(none: this scheme takes no options)"}')
        try:
            out[key] = float(value)
        except ValueError:
            out[key] = value
    return out


def _snap_plant_rate(plant, where) -> None:
    """Design for the shortest rate the plant's fs_hz stands for (1024.000524 -> 1024)."""
    from rths_common.timebase import format_hz, nominal_rate
    fs = nominal_rate(plant.fs_hz)
    if fs != plant.fs_hz:
        _log(f'design: {where}: fs_hz {format_hz(plant.fs_hz)} Hz is {format_hz(fs)} Hz to '
             'the six digits rates are compared with; designing for it')
        plant.fs_hz = fs


def cmd_compensate(args) -> int:
    """``rths compensate``."""
    from rths_common.timebase import format_hz, same_rate, sampling_rate_hz

    from .filters import CausalFilter
    from .io import write_csv_columns
    from .params import load_compensator_params
    params = load_compensator_params(args.params)
    cols = read_columns(args.csv, ('time', 'command'))
    fs = sampling_rate_hz(cols['time'], args.csv)
    if not same_rate(fs, params['fs_hz']):
        raise ValueError(f'{args.csv}: sampling rate {format_hz(fs)} Hz differs from fs_hz '
                         f'{format_hz(params["fs_hz"])} of {args.params}; resample or '
                         'redesign')
    filt = CausalFilter(params['taps'], params['denominator'])
    out = filt.apply(cols['command'])
    write_csv_columns(args.out, {'time': cols['time'], 'command': cols['command'],
                                 'compensated': out})
    print(f'{params["scheme"]} compensator applied to {out.size} samples; wrote {args.out}')
    return 0


def cmd_unstable_zeros(args) -> int:
    """``rths unstable-zeros``."""
    import numpy as np

    from .plants import discrete_zeros, unstable_zero_threshold_hz
    seed = {'3pole': 41.0, '4pole': 42.0}
    for kind in ('3pole', '4pole'):
        fs = unstable_zero_threshold_hz(kind)
        print(f'{kind}: a ZOH zero leaves the unit circle above fs = {fs:.2f} Hz '
              f'(seed Appendix I: ~{seed[kind]:.0f} Hz)')
    if args.plot:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
        fss = np.logspace(0.0, np.log10(args.fs_max), 300)
        fig, axes = plt.subplots(1, 2, figsize=(11, 4))
        for ax, kind in zip(axes, ('3pole', '4pole'), strict=True):
            mods = [np.sort(np.abs(discrete_zeros(kind, f)))[::-1] for f in fss]
            width = max(len(m) for m in mods)
            arr = np.full((len(fss), width), np.nan)
            for i, m in enumerate(mods):
                arr[i, :len(m)] = m
            ax.plot(fss, arr)
            ax.axhline(1.0, color='k', ls='--', lw=0.8)
            ax.axvline(unstable_zero_threshold_hz(kind), color='r', ls=':', lw=0.8)
            ax.set_xscale('log')
            ax.set_xlabel('sampling frequency [Hz]')
            ax.set_ylabel('|zero|')
            ax.set_title(f'{kind} model (Figure I.1)')
            ax.grid(True, which='both', alpha=0.3)
        fig.tight_layout()
        fig.savefig(args.plot, dpi=110)
        plt.close(fig)
        print(f'wrote {args.plot}')
    return 0


def cmd_bench_compensators(args) -> int:
    """``rths bench compensators``."""
    from . import bench
    from . import design as dsg
    eps = dsg.DEFAULT_EPSILON if args.epsilon is None else args.epsilon
    result = bench.run_study(seed=args.seed, noise_m=args.noise_m, eval_s=args.eval_s,
                             epsilon=eps)
    bench.write_json(args.out, result)
    print('target                                                   measured         limit')
    for name, got, limit, ok in bench.targets(result):
        print(f'{"PASS" if ok else "MISS"}  {name}: {got}  ({limit})')
    model = result['_extra']['model']
    print(f'identified plant: ARX na={model.na} nb={model.nb} d={model.d}')
    print(f'wrote {args.out}')
    if args.plots:

        from .identification import save_plant
        for path in bench.make_plots(result, args.plots):
            print(f'wrote {path}')
        path = save_plant(os.path.join(args.plots, 'plant.yaml'), model,
                          result['_extra']['selection'])
        print(f'wrote {path} (the identified plant, for rths design)')
    return 0
