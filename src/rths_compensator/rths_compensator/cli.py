"""Sub-commands this package adds to the ``rths`` command (see rths_bringup.cli).

* ``rths identify``        ARX identification + model selection -> plant.yaml
* ``rths design``          compensator design -> ROS 2 parameters file (or ``--auto``)
* ``rths compensate``      apply a designed compensator offline to a CSV command
* ``rths unstable-zeros``  Appendix I: sampling-frequency threshold of the unstable zero
* ``rths bench compensators``  the seed's numerical study (section 4.3.3) -> JSON (+ plots)
"""

import os
import sys

from rths_common.columns import LENGTH_UNITS, TIME_UNITS, read_columns

from .schemes import COUPLED_SCHEME, SCHEMES, designed

# Imports of the commands' code sit in the command functions: rths imports this module
# to build its parser, and every rths command would pay for SciPy, matplotlib and ROS.

#: Defaults of the coupled N x N FIR (``rths design`` of an ``rths identify --channels`` plant):
#: the maRTHS benchmark's ``mimo`` controller (``rths_bench.marths.identify_mimo``).
COUPLED_DEFAULTS = {'n_taps': 48, 'fc_hz': 30.0, 'lowpass_hz': 100.0, 'stop_weight': 0.03,
                    'gain_weight': 1e-3}
#: The coupled FIR's options without a flag of their own (``--option KEY=VALUE``).
COUPLED_OPTIONS = ('lowpass_hz', 'stop_weight', 'gain_weight')
#: What a design reports beside its options, kept in the provenance.
DESIGN_RESULTS = ('a_tilde', 'model', 'q', 'solver', 'auto_score', 'bandwidth_hz')
#: Design option -> the ``rths design`` argument that gives it (``--option KEY=VALUE`` gives
#: any other option a scheme names).
OPTION_ARGS = {'n_taps': 'taps', 'fc_hz': 'fc', 'epsilon': 'epsilon', 'zero_tol': 'zero_tol',
               'gain_weight': 'gain_weight', 'alpha': 'alpha', 'poles': 'mff_model',
               'delay_ms': 'delay_ms', 'band_hz': 'band'}


def _log(msg):
    print(msg, file=sys.stderr, flush=True)


def register(commands, benches):
    """Add this package's ``rths <command>`` and ``rths bench <name>`` parsers."""
    p = commands.add_parser(
        'identify', help='identify the actuator plant from a recorded run -> plant.yaml',
        description='Identify the actuator (command -> measured displacement) from one recorded '
                    'run, at its own uniform rate. Default (--method oe): the dead time is '
                    'estimated from the data and searched around; ARX models na <= --na-max, '
                    'nb <= --nb-max fitted on the first part of the run are refined by output '
                    'error (not biased by measurement noise) and the order is chosen on the '
                    'held-out last part (--validation-fraction) by BIC of the simulation '
                    'error. Prints, saves (plant.yaml) and plots (--plot) the validation fit: '
                    'simulation NRMSE and the model\'s frequency response beside the record\'s '
                    'with its uncertainty; warns when the choice sits at a grid edge or the '
                    'fit is poor. --method arx-grid is the seed\'s ARX grid with a BIC '
                    'histogram over --record-s records (section 4.3.1.2). --channels N (N > 1): '
                    'the N x N plant of N actuators on one specimen from one test in which every '
                    'actuator had its own uncorrelated excitation: a state-space model '
                    '(subspace fit, order <= --order-max chosen on the held-out part by BIC of '
                    'the simulation error), the cross-coupling printed and saved (each '
                    'command\'s effect on every other actuator relative to that actuator\'s own, '
                    'at DC and at its peak over --band), with its JSON report and plot beside '
                    '--out (docs/multi_actuator.md).')
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument('--csv', help='identification run as CSV (time, command, measured)')
    src.add_argument('--bag', help='identification run as a rosbag2 bag directory')
    p.add_argument('--val-csv', help='arx-grid: separate validation run (CSV); default: split')
    p.add_argument('--columns', default=None, metavar='TIME,COMMAND,MEASURED',
                   help='CSV: the time, command and measured-displacement columns, by header '
                        'name or 0-based index (default time,command,measured), e.g. '
                        '"Time,Cmd,Disp" or 0,1,2; with --channels N: time, the N commands, '
                        'then the N measured displacements (default time,command_1,..,'
                        'command_N,measured_1,..,measured_N)')
    p.add_argument('--channels', type=int, default=1, metavar='N',
                   help='actuators identified together (1): N > 1 identifies the N x N plant '
                        'and its cross-coupling from one record of every actuator excited at '
                        'once (a CSV with N command and N measured columns, or the bag of a '
                        'run with N actuators)')
    p.add_argument('--order-max', type=int, default=None,
                   help='--channels N: largest state-space order tried (12)')
    p.add_argument('--band', type=float, default=None,
                   help='--channels N: band [Hz] of the cross-coupling report (default: the '
                        'band that holds 99.5 %% of the commands\' power)')
    p.add_argument('--time-unit', choices=TIME_UNITS, default=None,
                   help='CSV: unit of the time column (default: from the header, e.g. '
                        '"Time (ms)" or "time [s]", else s)')
    p.add_argument('--length-unit', choices=LENGTH_UNITS, default=None,
                   help='CSV: unit of the command and measured columns (default: from the '
                        'header, e.g. "Cmd (mm)", else m)')
    p.add_argument('--out', required=True, help='plant file to write (YAML)')
    p.add_argument('--method', default='oe', choices=('oe', 'arx-grid'),
                   help='oe (default): dead time from the data, output-error refinement, '
                        'order on the held-out part; arx-grid: the seed\'s ARX grid')
    p.add_argument('--na-max', type=int, default=None, help='largest na (oe 6, arx-grid 29)')
    p.add_argument('--nb-max', type=int, default=None, help='largest nb (oe 8, arx-grid 29)')
    p.add_argument('--d-min', type=int, default=None,
                   help='smallest dead time d [samples] (default: searched around the '
                        'estimate)')
    p.add_argument('--d-max', type=int, default=None,
                   help='largest dead time d [samples] (default: searched around the '
                        'estimate; arx-grid 0)')
    p.add_argument('--max-delay-ms', type=float, default=None,
                   help='oe: longest dead time the estimate considers [ms] (100)')
    p.add_argument('--validation-fraction', type=float, default=1.0 / 3.0,
                   help='oe: last fraction of the run held out for the order choice and the '
                        'validation fit (1/3)')
    p.add_argument('--plot', default=None,
                   help='oe: PNG of the validation fit (default: beside --out, *_fit.png)')
    p.add_argument('--no-plot', action='store_true', help='oe: do not draw the plot')
    p.add_argument('--record-s', type=float, default=10.0,
                   help='arx-grid: record length [s] (10)')
    p.add_argument('--criterion', default='bic', choices=('mse', 'fit', 'aic', 'bic'),
                   help='arx-grid: selection criterion (bic, as the seed)')
    p.add_argument('--error', default='simulation', choices=('simulation', 'prediction'),
                   help='arx-grid: validation error, simulated output (default) or one-step '
                        'prediction')
    p.set_defaults(func=cmd_identify)

    from .schemes import DESIGN_DEFAULTS as DD
    from .schemes import LONG_DEAD_TIME_FC_HZ, LONG_DEAD_TIME_S, LOW_RATE_HZ
    p = commands.add_parser(
        'design', help='design a delay compensator from plant.yaml -> ROS 2 parameters file',
        description='Design the FIR compensator (ls, wls, mm; eq. 28-36) or a comparison '
                    'compensator (inverse eq. 2, mff eq. 4, npz eq. 8, zpetc eq. 12, zmetc '
                    'eq. 14) for the plant and write the compensator node parameters. '
                    f'Defaults (also rths run\'s): {DD["scheme"]}, n={DD["n_taps"]}, '
                    f'fc={DD["fc_hz"]:g} Hz ({LONG_DEAD_TIME_FC_HZ:g} Hz from a lag to predict '
                    f'(dead time and unstable zeros) of {1e3 * LONG_DEAD_TIME_S:g} ms at up '
                    f'to {LOW_RATE_HZ:g} Hz), '
                    f'epsilon={DD["epsilon"]}, gain weight '
                    f'{DD["gain_weight"]:g}. Prints and records the predictions: the '
                    'compensator alone (gain peak, high-frequency gain, command for a unit step '
                    'and for the record), the compensated loop on the model and on the '
                    'record\'s held-out part. Refuses (exit 2, nothing written) unstable, '
                    'non-finite or constraint-violating designs, and designs whose command for '
                    'the record\'s motion in the design band would exceed the actuator\'s '
                    'stroke, velocity or acceleration limits (--limits; --force writes it '
                    'anyway). With --auto --bandwidth HZ it searches scheme, n and fc. '
                    'Schemes: '
                    + '; '.join(f'{n}: {s.summary}' for n, s in SCHEMES.items() if s.designer))
    p.add_argument('--plant', required=True,
                   help='plant file from rths identify, or the updated_model.yaml of rths '
                        'discrepancy --scenario actuator (its time_delay and linear loop '
                        'loads folded into the ARX; its Coulomb and cubic loads written as '
                        "the compensator's load feed-forward, feedforward_*; other effects "
                        'refused)')
    p.add_argument('--scheme', default=None, choices=designed(),
                   help=f'compensator scheme ({DD["scheme"]})')
    p.add_argument('--taps', type=int, default=None,
                   help=f'FIR length n of H ({DD["n_taps"]}; an N x N plant: '
                        f'{COUPLED_DEFAULTS["n_taps"]} per pair)')
    p.add_argument('--fc', type=float, default=None,
                   help=f'FIR passband edge fc [Hz] (default {DD["fc_hz"]:g}, the seed\'s; '
                        f'{LONG_DEAD_TIME_FC_HZ:g} for a plant whose FIR predicts a lag (dead '
                        f'time and unstable zeros) of {1e3 * LONG_DEAD_TIME_S:g} ms or more '
                        f'at a rate up to {LOW_RATE_HZ:g} '
                        'Hz: the FIR\'s error rises past fc the faster the longer the delay)')
    p.add_argument('--epsilon', type=float, default=None,
                   help=f'FIR passband tolerance on |T_com - 1| ({DD["epsilon"]})')
    p.add_argument('--gain-weight', type=float, default=None,
                   help='ls/wls: weight of the compensator\'s own gain |G|^2 above fc '
                        f'({DD["gain_weight"]:g}; 0: the seed\'s objective, T_com -> 1 over '
                        'the whole band)')
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
    p.add_argument('--limits', default=None,
                   help='bridge params file whose stroke_m, velocity_m_s, acceleration_m_s2 '
                        'bound the command (default: config/bridge.yaml of the repo)')
    p.add_argument('--force', action='store_true',
                   help='write a design that exceeds the limits (the bridge\'s supervisor '
                        'still stops any command beyond them)')
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


def channel_columns(n: int) -> tuple:
    """Names of the columns of an N-actuator record: time, the commands, the measured."""
    if n == 1:
        return ('time', 'command', 'measured')
    return (('time',) + tuple(f'command_{i}' for i in range(1, n + 1))
            + tuple(f'measured_{i}' for i in range(1, n + 1)))


def _column_spec(args) -> tuple:
    """``(columns, units)`` of --columns/--time-unit/--length-unit for the column reader."""
    n = int(getattr(args, 'channels', 1) or 1)
    names = channel_columns(n)
    given = getattr(args, 'columns', None)
    cells = [c.strip() for c in str(given or ','.join(names)).split(',')]
    if len(cells) != len(names) or not all(cells):
        if n == 1:
            raise ValueError(f'--columns {given!r}: give three columns, time, command and '
                             'measured, by name or 0-based index, e.g. "Time,Cmd,Disp" or 0,1,2')
        raise ValueError(f'--columns {given!r}: --channels {n} needs {len(names)} columns, '
                         f'{", ".join(names)}, by name or 0-based index')
    columns = {nm: int(c) if c.isdigit() else c for nm, c in zip(names, cells, strict=True)}
    units = {}
    if getattr(args, 'time_unit', None):
        units['time'] = args.time_unit
    if getattr(args, 'length_unit', None):
        units.update({nm: args.length_unit for nm in names[1:]})
    return columns, units


def read_run(path, columns=None, units=None):
    """``(t, u, y, rate, report)`` of a CSV run in SI; ``report`` names columns and units."""
    from rths_common.timebase import infer_rate
    columns = columns or {n: n for n in ('time', 'command', 'measured')}
    report = {}
    cols = read_columns(path, columns, units=units or None, report=report,
                        contract='time, command and measured displacement (--columns)')
    rate = infer_rate(cols['time'], path)
    return cols['time'], cols['command'], cols['measured'], rate, report


def _read_run(args, path):
    columns, units = _column_spec(args)
    t, u, y, rate, report = read_run(path, columns, units)
    _log(f'{path}: sampling rate {rate}')
    _log(f'{path}: ' + '; '.join(f'{n} = column {c!r} in {unit or "SI"} ({src})'
                                 for n, (c, unit, src) in report.items()))
    if rate.fs_hz < 100.0:
        _log(f'WARNING: {path}: {rate.fs_hz:.6g} Hz is low for an actuator record; if the time '
             'column is in milliseconds give --time-unit ms (or write "Time (ms)" in the header)')
    return t, u, y, rate.fs_hz


def _read_source(args):
    """``(t, u, y, fs, record)`` of --bag or --csv; ``record`` says how to read it again."""
    from rths_common.bagio import read_identification
    from rths_common.timebase import sampling_rate_hz
    if args.bag:
        t, u, y = read_identification(args.bag)
        fs = sampling_rate_hz(t, args.bag)
        _check_causality(u, y, fs, args.bag)
        return t, u, y, fs, {'kind': 'bag', 'path': os.path.abspath(args.bag)}
    t, u, y, fs = _read_run(args, args.csv)
    _check_causality(u, y, fs, args.csv)
    columns, units = _column_spec(args)
    return t, u, y, fs, {'kind': 'csv', 'path': os.path.abspath(args.csv),
                         'columns': columns, 'units': units}


def _check_causality(u, y, fs, where):
    """Refuse a record whose measured signal leads the command (columns swapped)."""
    from .causality import check_causality
    lag = check_causality(u, y, fs, str(where))
    _log(f'identify: the measured signal lags the command by {lag * 1e3:.2f} ms')


def read_record(record: dict):
    """``(u, y, fs)`` of the identification record a plant.yaml names (ValueError if gone)."""
    import os

    from rths_common.bagio import read_identification
    from rths_common.timebase import sampling_rate_hz
    path = record.get('path', '')
    if not os.path.exists(path):
        raise OSError(f'{path}: identification record not found')
    if record.get('kind') == 'bag':
        t, u, y = read_identification(path)
        return u, y, sampling_rate_hz(t, path)
    t, u, y, rate, _ = read_run(path, record.get('columns'), record.get('units'))
    return u, y, rate.fs_hz


def cmd_identify(args) -> int:
    """``rths identify``."""
    from ._blas import limit_blas_threads
    limit_blas_threads(1)
    if args.channels < 1:
        raise ValueError(f'--channels {args.channels}: give the number of actuators, >= 1')
    if args.channels > 1:
        return _identify_channels(args)
    for flag in ('order_max', 'band'):
        if getattr(args, flag) is not None:
            raise ValueError(f'--{flag.replace("_", "-")} belongs to --channels N (N > 1); '
                             'one actuator\'s order is --na-max/--nb-max')
    if args.max_delay_ms is None:
        args.max_delay_ms = 100.0
    if args.method == 'arx-grid':
        return _identify_arx_grid(args)
    if args.val_csv:
        raise ValueError('--val-csv belongs to --method arx-grid; the default method holds out '
                         'the last --validation-fraction of the run')
    from rths_common.progress import Progress
    from rths_common.timebase import format_hz

    from .estimation import IdentOptions, identify_record
    from .identification import save_plant
    t, u, y, fs, record = _read_source(args)
    opts = IdentOptions(max_delay_s=args.max_delay_ms * 1e-3,
                        validation_fraction=args.validation_fraction,
                        d_min=args.d_min, d_max=args.d_max)
    for name in ('na_max', 'nb_max'):
        value = getattr(args, name)
        if value is not None:
            if value < 1:
                raise ValueError(f'--{name.replace("_", "-")} must be >= 1, got {value}')
            setattr(opts, name, value)
    n_val = int(round(u.size * args.validation_fraction))
    _log(f'identify: fs = {format_hz(fs)} Hz, {u.size} samples ({u.size / fs:.4g} s); the last '
         f'{n_val / fs:.4g} s are held out for validation')
    with Progress(0, 'identify: models') as bar:
        ident = identify_record(u, y, fs, opts, progress=bar.report, log=_log)
    info = dict(ident.info, source=record['path'])
    record['split'] = int(ident.info['split'])
    info['record'] = record
    model = ident.model
    save_plant(args.out, model, info)
    print(identification_text(ident))
    if not args.no_plot:
        from .estimation import plot_identification
        plot = args.plot or _beside(args.out, '_fit.png')
        plot_identification(ident, plot, title=f'{record["path"]}')
        print(f'wrote {plot}')
    print(f'wrote {args.out}')
    return 0


#: Options of one actuator's identification that --channels N does not take.
SINGLE_CHANNEL_OPTIONS = ('val_csv', 'na_max', 'nb_max', 'd_min', 'd_max', 'max_delay_ms')


def _identify_channels(args) -> int:
    """``rths identify --channels N``: the N x N plant and its cross-coupling."""
    from rths_common.progress import Progress
    from rths_common.timebase import format_hz

    from . import multichannel as mc
    n = args.channels
    if args.method != 'oe':
        raise ValueError(f'--method {args.method} identifies one actuator; --channels {n} fits '
                         'the N x N state-space model (drop --method)')
    for name in SINGLE_CHANNEL_OPTIONS:
        if getattr(args, name) is not None:
            raise ValueError(f'--{name.replace("_", "-")} belongs to one actuator\'s '
                             f'identification; --channels {n} chooses the state-space order '
                             '(--order-max) on the held-out part')
    order_max = 12 if args.order_max is None else args.order_max
    if order_max < 1:
        raise ValueError(f'--order-max must be >= 1, got {order_max}')
    if args.band is not None and not args.band > 0:
        raise ValueError(f'--band must be > 0 Hz, got {args.band}')
    t, u, y, fs, record = _read_channels(args, n)
    for i in range(n):
        _check_causality(u[:, i], y[:, i], fs, f'{record["path"]}: actuator {i + 1}')
    n_val = int(round(u.shape[0] * args.validation_fraction))
    _log(f'identify: {n} actuators, fs = {format_hz(fs)} Hz, {u.shape[0]} samples '
         f'({u.shape[0] / fs:.4g} s); the last {n_val / fs:.4g} s are held out for the order')
    with Progress(0, 'identify: orders') as bar:
        model, report = mc.identify_record(u, y, fs, args.validation_fraction,
                                           n_max=order_max, horizon=max(30, order_max + 1),
                                           band_hz=args.band, progress=bar.report)
    report['source'] = record['path']
    report['record'] = record
    mc.save_plant(args.out, model, report)
    json_path = _beside(args.out, '_identification.json')
    _write_json(json_path, report)
    print(channels_text(report))
    if not args.no_plot:
        plot = args.plot or _beside(args.out, '_fit.png')
        mc.plot_identification(model, u, y, report, plot, title=record['path'])
        print(f'wrote {plot}')
    print(f'wrote {args.out}')
    print(f'wrote {json_path}')
    return 0


def _write_json(path, obj) -> None:
    import json

    from rths_common.files import atomic_open

    from .identification import _plain
    with atomic_open(path) as handle:
        handle.write(json.dumps(_plain(obj), indent=2) + '\n')


def _read_channels(args, n: int):
    """``(t, u, y, fs, record)`` of --bag or --csv with ``n`` actuators (samples x n)."""
    import numpy as np

    from rths_common.bagio import read_identification_channels
    from rths_common.timebase import infer_rate, sampling_rate_hz
    if args.bag:
        t, u, y = read_identification_channels(args.bag)
        width = u.shape[1]
        if width != n:
            raise ValueError(f'{args.bag}: the bag holds {width} actuator channels, not {n}; '
                             f'give --channels {width}')
        return t, u, y, sampling_rate_hz(t, args.bag), {
            'kind': 'bag', 'path': os.path.abspath(args.bag)}
    columns, units = _column_spec(args)
    report = {}
    names = channel_columns(n)
    cols = read_columns(args.csv, columns, units=units or None, report=report,
                        contract=', '.join(str(columns[nm]) for nm in names)
                        + f' (--columns; --channels {n})')
    rate = infer_rate(cols['time'], args.csv)
    _log(f'{args.csv}: sampling rate {rate}')
    _log(f'{args.csv}: ' + '; '.join(f'{nm} = column {c!r} in {unit or "SI"} ({src})'
                                     for nm, (c, unit, src) in report.items()))
    u = np.column_stack([cols[f'command_{i}'] for i in range(1, n + 1)])
    y = np.column_stack([cols[f'measured_{i}'] for i in range(1, n + 1)])
    return cols['time'], u, y, rate.fs_hz, {'kind': 'csv', 'path': os.path.abspath(args.csv),
                                            'columns': columns, 'units': units}


def channels_text(report: dict) -> str:
    """Return the printed summary of an N x N identification: choice, fit, coupling."""
    n, cc = report['n_channels'], report['cross_coupling']
    val = report['validation']
    held_s = (report['samples'] - report['split']) / report['fs_hz']
    lines = [f'chosen: state-space order {report["order"]} for {n} actuators '
             f'({report["criterion"]}; orders 1-{report["order_max"]})',
             f'validation fit on the held-out {held_s:.4g} s: simulation NRMSE '
             + ', '.join(f'actuator {i + 1} {v:.3f} %' for i, v in enumerate(val['nrmse_pct'])),
             'static gains (row: measured actuator, column: command): '
             + '; '.join(' '.join(f'{v:.4f}' for v in row) for row in cc['dc_gain']),
             f'cross-coupling, relative to the actuator\'s own response (DC / peak over '
             f'0-{cc["band_hz"]:.3g} Hz):']
    for i in range(n):
        for j in range(n):
            if i != j:
                lines.append(f'  command {j + 1} -> actuator {i + 1}: '
                             f'{100 * cc["dc_rel"][i][j]:.2f} % / '
                             f'{100 * cc["peak_rel"][i][j]:.2f} %')
    lines.append(f'  largest: {100 * cc["dc_rel_max"]:.2f} % at DC, '
                 f'{100 * cc["peak_rel_max"]:.2f} % at its peak')
    lines += [f'WARNING: {w}' for w in report['warnings']]
    return '\n'.join(lines)


def _beside(path, suffix):
    import os
    stem, _ = os.path.splitext(str(path))
    return stem + suffix


def identification_text(ident) -> str:
    """Return the printed summary of an identification (choice, fit, warnings)."""
    m, info = ident.model, ident.info
    val = info['validation']
    lines = [
        f'chosen: na={m.na} nb={m.nb} d={m.d} ({1e3 * m.d / m.fs_hz:.2f} ms dead time), '
        f'{"stable" if m.is_stable() else "UNSTABLE"}, DC gain {m.dc_gain():.4f} '
        f'({info["method"]}, {info["criterion"]})',
        f'validation fit on the held-out {val["n_validation"] / m.fs_hz:.4g} s: simulation '
        f'NRMSE {val["nrmse_pct"]:.3f} % (in band 0-{info["band_hz"]:.3g} Hz: '
        f'{val["nrmse_band_pct"]:.3f} %); frequency response at most {val["frf_error_sigma"]:.1f} '
        f'standard deviations from the record\'s, {val["frf_error_pct"]:.2f} % beyond its '
        '+-2 std band',
        '  candidates: ' + '; '.join(info['candidates'][:4]),
    ]
    lines += [f'WARNING: {w}' for w in ident.warnings]
    return '\n'.join(lines)


def _identify_arx_grid(args) -> int:
    """``rths identify --method arx-grid``: the seed's grid and BIC histogram."""
    from rths_common.timebase import format_hz, same_rate

    from .causality import check_causality
    from .identification import identify, save_plant, split_records
    t, u, y, fs, record = _read_source(args)
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
    na_max, nb_max = args.na_max or 29, args.nb_max or 29
    d_max = args.d_max or 0
    if args.d_min:
        raise ValueError('--d-min belongs to the default method; arx-grid searches 0..--d-max')
    _log(f'identify: fs = {format_hz(fs)} Hz, {len(train)} training and {len(val)} validation '
         f'records of {args.record_s} s; grid {na_max} x {nb_max} x {d_max + 1}')
    from rths_common.progress import Progress

    with Progress(0, 'identify: ARX models') as bar:
        model, info, _ = identify(train, val, fs, na_max, nb_max, d_max,
                                  args.criterion, args.error, progress=bar.report)
        bar.update(bar.total)                         # (the grid reports every 100 models)
    info['source'] = record['path']
    info['record'] = record
    save_plant(args.out, model, info)
    print(f'selected ({args.criterion}): na={model.na} nb={model.nb} d={model.d}, '
          f'stable={model.is_stable()}, DC gain {model.dc_gain():.4f}')
    for crit in ('mse', 'fit', 'aic', 'bic'):
        print(f'  {crit}: ' + '; '.join(info[crit]['top'][:3]))
    print(f'wrote {args.out}')
    return 0


def cmd_design(args) -> int:
    """``rths design``."""
    from . import design as dsg
    from ._blas import limit_blas_threads
    from .identification import load_plant
    limit_blas_threads(1)
    if _coupled_plant(args.plant):
        return _design_coupled(args)
    if args.taps is None:
        args.taps = dsg.DESIGN_DEFAULTS['n_taps']
    plant = load_plant(args.plant)
    _snap_plant_rate(plant, args.plant)
    zero_tol = 1.0 if args.zero_tol is None else args.zero_tol
    if not 0 < zero_tol <= 1:
        raise ValueError(f'--zero-tol must lie in (0, 1], got {zero_tol}')
    scheme = args.scheme or dsg.DESIGN_DEFAULTS['scheme']
    if args.zero_tol is not None and not args.auto and not SCHEMES.entry(scheme).fir:
        raise ValueError(f'--zero-tol applies to the FIR schemes ({", ".join(dsg.FIR_SCHEMES)}) '
                         f'and --auto, not to --scheme {scheme}; drop it')
    if args.gain_weight is not None and (
            args.auto or 'gain_weight' not in SCHEMES.entry(scheme).options):
        raise ValueError('--gain-weight applies to the least-squares FIR schemes (ls, wls); '
                         'drop it')
    if args.auto:
        comp, band = _design_auto(args, plant, zero_tol)
        make, band_of, adapt = (lambda weight: comp), (lambda c: band), False
    else:
        make, band_of, adapt = _design_one(args, plant, scheme, zero_tol)
    return _assess_and_write(args, plant, make, band_of, adapt)


def _coupled_plant(path) -> bool:
    """Tell whether the plant file ``path`` holds an N x N plant (``kind: state_space``)."""
    import os

    from rths_common import yamlfile
    if not os.path.isfile(path):
        return False                  # load_plant says what is missing
    data = yamlfile.load(path)
    return isinstance(data, dict) and data.get('kind') == 'state_space'


#: ``rths design`` options of one actuator's design, refused for an N x N plant (flag: default).
SINGLE_DESIGN_OPTIONS = {'scheme': None, 'epsilon': None, 'zero_tol': None, 'gain_weight': None,
                         'delay_ms': None, 'auto': False, 'bandwidth': None, 'alpha': 7.0,
                         'mff_model': '3pole'}


def _design_coupled(args) -> int:
    """``rths design`` of an N x N plant: the coupled FIR (``coupled_taps``)."""
    import numpy as np

    from rths_common import yamlfile

    from . import multichannel as mc
    from .params import check_filter_cost, write_compensator_params
    for name, default in SINGLE_DESIGN_OPTIONS.items():
        if getattr(args, name) != default:
            flag = '--' + name.replace('_', '-')
            raise ValueError(f'{flag} belongs to one actuator\'s design; {args.plant} is an '
                             'N x N plant: its coupled FIR takes --taps, --fc and --option '
                             f'{"/".join(COUPLED_OPTIONS)}=VALUE')
    doc = yamlfile.load(args.plant)
    model = mc.model_from_dict(doc, args.plant)
    n = model.b.shape[1]
    if model.c.shape[0] != n:
        raise ValueError(f'{args.plant}: {model.c.shape[0]} measured channels for {n} commands; '
                         'a coupled FIR needs one of each per actuator')
    opts = dict(COUPLED_DEFAULTS)
    opts.update({k: v for k, v in (('n_taps', args.taps), ('fc_hz', args.fc)) if v is not None})
    opts.update(_options(args.option, COUPLED_OPTIONS))
    n_taps, fs = int(opts['n_taps']), model.fs_hz
    if n_taps < 1:
        raise ValueError(f'--taps must be >= 1, got {n_taps}')
    for key in ('fc_hz', 'lowpass_hz'):
        if not 0 < float(opts[key]) < fs / 2:
            raise ValueError(f'{key} = {opts[key]}: give a frequency in (0, fs/2 = {fs / 2:g}) Hz')
    check_filter_cost(n * n_taps, fs, f'--taps {n_taps} for {n} actuators')
    taps = mc.design_coupled_fir(model.freq_resp, fs, n_taps, float(opts['fc_hz']),
                                 float(opts['lowpass_hz']), float(opts['stop_weight']),
                                 float(opts['gain_weight']))
    pred = mc.coupled_prediction(model, taps, float(opts['lowpass_hz']), args.band)
    if not np.all(np.isfinite(taps)):
        raise ValueError(f'{args.plant}: the design gave non-finite taps; nothing written')
    provenance = dict({k: float(v) for k, v in opts.items()}, plant=os.path.abspath(args.plant),
                      n_actuators=n, **{k: v for k, v in pred.items()
                                        if isinstance(v, (int, float))})
    write_compensator_params(args.out, [1.0], [1.0], fs, COUPLED_SCHEME, provenance,
                             coupled_taps=taps)
    print(f'coupled FIR: {n} x {n} actuators, n={n_taps} taps per pair, fc {opts["fc_hz"]:g} Hz, '
          f'target low-pass {opts["lowpass_hz"]:g} Hz (order 4)')
    print(f'predicted on the plant model over 0-{args.band:g} Hz: tracking error |(P G)_ii - L| '
          f'up to {pred["tracking_error_pct"]:.2f} % of L, cross-coupling up to '
          f'{pred["residual_coupling_pct"]:.2f} % of the diagonal (uncompensated '
          f'{pred["plant_coupling_pct"]:.2f} %), compensator gain up to '
          f'{pred["gain_peak"]:.3g} (at {pred["gain_peak_hz"]:.4g} Hz)')
    print('limits: the bridge checks every actuator\'s command and the interface pose before '
          'it is written (this design is not checked against them here)')
    print(f'wrote {args.out}')
    return 0


def _design_auto(args, plant, zero_tol):
    from . import design as dsg
    if not args.bandwidth:
        raise ValueError('--auto needs --bandwidth HZ (the operating bandwidth)')
    eps = dsg.DEFAULT_EPSILON if args.epsilon is None else args.epsilon
    _log(f'design --auto: searching for 0-{args.bandwidth} Hz')
    from rths_common.progress import Progress

    with Progress(0, 'design --auto', 'candidates') as bar:
        comp, table = dsg.auto_design(plant, args.bandwidth, epsilon=eps, zero_tol=zero_tol,
                                      progress=bar.report)
    band = args.bandwidth
    print('score = |delay| [ms] + gain error [dB] + 0.1 x max(0, loop gain |P G| above the '
          'band - 6 dB) + 1e-4 x coefficients (lower is better); top candidates:')
    for row in table[:8]:
        if row['error']:
            continue
        print(f"  {row['scheme']:6s} n={row['n_taps']!s:>4} fc={row['fc_hz']!s:>6} "
              f"score {row['score']:.3f}: delay {row['delay_ms']:+.3f} ms, gain error "
              f"{row['gain_error_db']:.3f} dB, loop gain above the band "
              f"{row['highpass_gain_db']:.1f} dB, {row['n_coefficients']} coefficients")
    top = table[0]
    print(f"chose {top['scheme']} n={top['n_taps']} fc={top['fc_hz']}: lowest score")
    return comp, band


def _design_one(args, plant, scheme, zero_tol):
    """Design ``scheme`` from its registry entry: the defaults, then the flags, then --option."""
    from . import design as dsg
    entry = SCHEMES.entry(scheme, '--scheme')
    given = dict(vars(args), zero_tol=zero_tol)
    opts = {key: given[OPTION_ARGS[key]] for key in entry.options
            if key in OPTION_ARGS and given[OPTION_ARGS[key]] is not None}
    opts.update(_options(args.option, entry.options))
    if entry.fir:
        from .params import check_filter_cost
        check_filter_cost(args.taps, plant.fs_hz, f'--taps {args.taps}')

        def make(weight):
            return dsg.design_default(plant, scheme=scheme, **dict(
                opts, **({'gain_weight': weight} if weight is not None else {})))
        # the gain weight adapts to the limits unless the user chose it
        adapt = 'gain_weight' in entry.options and 'gain_weight' not in opts
        return make, (lambda comp: comp.info['fc_hz']), adapt
    comp = dsg.design(plant, scheme, **opts)
    return (lambda weight: comp), (lambda c: args.band), False


def _limits(args):
    """Return the limits of --limits, else of the repo's config/bridge.yaml (None if absent)."""
    from .assessment import DesignLimits
    path = args.limits
    if path is None:
        root = os.environ.get('RTHS_ROOT')
        path = os.path.join(root, 'config', 'bridge.yaml') if root else None
        if path is None or not os.path.isfile(path):
            return None
    return DesignLimits.from_bridge_params(path)


def _plant_record(plant_path):
    """``(u, y, split, note)`` of the identification record named in plant.yaml, if readable."""
    import yaml
    with open(plant_path, encoding='utf-8') as handle:
        doc = yaml.safe_load(handle) or {}
    record = (doc.get('selection') or {}).get('record')
    if not record:
        return None, None, None, 'the plant file names no identification record'
    try:
        u, y, _ = read_record(record)
    except (OSError, ValueError) as err:
        return None, None, None, f'the identification record is not readable ({err})'
    split = int(record.get('split') or (2 * u.size) // 3)
    return u, y, split, f'record {record["path"]}'


def _assess_and_write(args, plant, make, band_of, adapt) -> int:
    import numpy as np

    from .assessment import design_within_limits
    from .params import write_compensator_params
    limits = _limits(args)
    u, y, split, note = _plant_record(args.plant)
    record = (u, y, split) if u is not None else None
    comp, band, pred, violations, ref_text, adapted = design_within_limits(
        plant, make, band_of, record, limits, adapt=adapt and u is not None)
    if not all(np.isfinite(v) for v in pred.values() if isinstance(v, float)):
        raise ValueError(f'{comp.scheme} design has non-finite predicted indicators; refused')
    if adapted:
        print(f'adapted to the limits: {adapted}')
    print(design_text(comp, band, pred, ref_text, note))
    if limits is None:
        print('limits: no bridge params file (--limits); the command was not checked')
    if violations and u is None and not args.force:
        print('WARNING: without the identification record the reference amplitude is assumed; '
              'the design is written, check it: ' + '; '.join(violations))
        violations = []
    if violations and not args.force:
        raise ValueError('design refused: ' + '; '.join(violations) + '. Fix: lower --fc, '
                         'fewer --taps, a larger --gain-weight or a looser --epsilon (or '
                         '--force to write it; the bridge still stops such a command)')
    for line in violations:
        print(f'WARNING (--force): {line}')
    prov = {'plant': os.path.abspath(args.plant), 'n_coefficients': int(comp.taps.size),
            'predicted_band_hz': float(band),
            'predicted_delay_ms': pred['delay_ms'],
            'predicted_gain_error_db': pred['gain_error_db'],
            'predicted_loop_gain_above_band_db': pred['loop_gain_above_band_db'],
            'compensator_gain_peak_db': pred['gain_peak_db'],
            'compensator_gain_peak_hz': pred['gain_peak_hz'],
            'compensator_hf_gain_db': pred['hf_gain_db'],
            'step_command_peak': pred['step_command_peak'],
            'reference': ref_text,
            'reference_command_ratio': pred['reference_command_ratio'],
            'record_tracking_pct': pred.get('record_tracking_pct'),
            'noise_command_peak_m': pred['noise_command_peak_m'],
            'noise_command_acceleration_m_s2': pred['noise_command_acceleration_m_s2'],
            'adapted_to_limits': adapted,
            'limits': limits.source if limits else None,
            'limits_exceeded': '; '.join(violations)}
    for key in SCHEMES.entry(comp.scheme).options + DESIGN_RESULTS:
        if key in comp.info:
            prov[key] = comp.info[key]
    from .feedforward import feedforward_params
    feedforward = feedforward_params(plant.loads)
    if feedforward:
        print('load feed-forward (the non-linear loads of the updated model, added to the '
              'command on the desired trajectory): '
              + ', '.join(f'{k} = {v:.6g}' for k, v in feedforward.items()))
    write_compensator_params(args.out, comp.taps, comp.denominator, comp.fs_hz, comp.scheme,
                             prov, feedforward=feedforward)
    print(f'wrote {args.out}')
    return 0


def design_text(comp, band, pred, ref_text, record_note) -> str:
    """Return the printed predictions of a design."""
    lines = [
        f'{comp.scheme}: {comp.taps.size} taps, denominator order {comp.denominator.size - 1}'
        + (f', fc {comp.info["fc_hz"]:g} Hz (the default for the '
           f'{comp.info["fc_default_lag_ms"]:.3g} ms lag its FIR predicts: dead time and '
           'unstable zeros)' if 'fc_default_lag_ms' in comp.info else ''),
        f'  compensator alone: gain peak {pred["gain_peak_db"]:.1f} dB at '
        f'{pred["gain_peak_hz"]:.3g} Hz, gain at Nyquist {pred["hf_gain_db"]:.1f} dB; command '
        f'for a unit step peaks at {pred["step_command_peak"]:.3g}; for the reference '
        f'({ref_text}) at {pred["reference_command_ratio"]:.3g} x its peak '
        f'({1e3 * pred["reference_command_peak_m"]:.3g} mm, '
        f'{pred["reference_command_velocity_m_s"]:.3g} m/s, '
        f'{pred["reference_command_acceleration_m_s2"]:.3g} m/s^2); for band-limited noise '
        f'over the band ({1e3 * pred["noise_peak_m"]:.3g} mm peak, 0.5 s fades, worst of '
        f'{pred["noise_draws"]}) at {1e3 * pred["noise_command_peak_m"]:.3g} mm, '
        f'{pred["noise_command_velocity_m_s"]:.3g} m/s, '
        f'{pred["noise_command_acceleration_m_s2"]:.3g} m/s^2',
        f'  loop P G on the model over 0-{band:g} Hz: delay {pred["delay_ms"]:+.3f} ms, gain '
        f'error {pred["gain_error_db"]:.3f} dB; loop gain above the band up to '
        f'{pred["loop_gain_above_band_db"]:.1f} dB',
    ]
    if pred.get('record_tracking_pct') is not None:
        lines.append(f'  loop on the record\'s held-out part (its own impulse response, '
                     f'{pred["record_memory_s"]:.2g} s, no model): predicted tracking error '
                     f'{pred["record_tracking_pct"]:.3f} % for the reference')
    else:
        lines.append(f'  loop on the record: not predicted ({record_note})')
    return '\n'.join(lines)


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
