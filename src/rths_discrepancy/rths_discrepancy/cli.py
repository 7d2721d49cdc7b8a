"""Sub-commands this package adds to the ``rths`` command (see rths_bringup.cli).

* ``rths discrepancy --scenario {specimen,actuator} --measured CSV|BAG [--model M.yaml]
  [--config DIR] --out DIR``: find, name and add the effect the model misses (issue 7).
  Given an RTHS bag (specimen scenario), the nominal model is the run's damper and the
  reference of the run is re-run with the updated model (:mod:`.rerun`).
* ``rths reference BAG --specimen-model M.yaml [--config DIR] [--out DIR]``: re-run the
  reference of an RTHS bag with a specimen model; print the RTHS-vs-reference error
  with the nominal and with that model.
* ``rths bench discrepancy --out FILE.json [--seeds N] [--quick] [--workers W]
  [--baselines]``: the self-test benchmark (confusion matrix, correct naming, false
  effects on controls, median gap closed); ``--baselines`` also runs pysindy and
  sysidentpy on the same records (:mod:`.baselines`).
"""

import json
import os
import sys

# Imports of the commands' code sit in the command functions: rths imports this module
# to build its parser, and every rths command would pay for SciPy, matplotlib and ROS.


def _say(msg):
    print(msg, file=sys.stderr, flush=True)


def _is_bag(path):
    return os.path.isdir(path) or str(path).lower().endswith(('.mcap', '.db3', '.bag'))


def _read_measured(path, scenario):
    """CSV path -> validated columns; a bag directory/.mcap/.db3 is read by ``io.read_bag``."""
    from rths_discrepancy import io as dio
    if _is_bag(path):
        return dio.validate(scenario, dio.read_bag(path, scenario), source=str(path))
    if not os.path.exists(path):
        raise OSError(f'--measured {path}: no such file')
    return dio.load_csv(path, scenario)


def _restoring_cmd(args) -> int:
    """``rths discrepancy --scenario restoring-force``: a measured specimen force."""
    from rths_discrepancy import restoring
    if args.model:
        raise ValueError('--model does not apply to the restoring-force scenario: its nominal '
                         'model m a + c v + k x is fitted from the record')
    if not os.path.exists(args.measured):
        raise OSError(f'--measured {args.measured}: no such file')
    if _is_bag(args.measured):
        data = restoring.validate(restoring.read_bag(args.measured), source=args.measured)
    else:
        data = restoring.load_csv(args.measured)
    from rths_common.progress import Progress

    with Progress(0, 'candidate models') as bar:
        res = restoring.run(data, out_dir=args.out, progress=bar.note,
                            source=os.path.basename(args.measured), count=bar.report)
    print(f"effect: {res['effect']}")
    for name, par in res['parameters'].items():
        print(f'  {name}: ' + ', '.join(f"{k} = {v:.6g} {par['unit'][k]}"
                                        for k, v in par.items() if k != 'unit'))
    mp = res['model_parameters']
    print(f"  model: m = {mp['m']:.6g} kg, c = {mp['c']:.6g} N s/m, k = {mp['k']:.6g} N/m")
    print(f"alignment: {res['alignment_samples']:+.2f} samples ({1e3 * res['alignment_s']:+.3f} "
          'ms)')
    print(f"held-out force NRMSE (later {100 * (1 - restoring.TRAIN_FRACTION):.0f} %): before "
          f"{res['nrmse_before']:.4f}, after {res['nrmse_after']:.4f}; gap closed "
          f"{res['gap_closed']:.3f}")
    print(f'wrote {args.out}/result.json, report.md and PNG plots')
    return 0


def csv_cmd(args) -> int:
    """``rths discrepancy-csv``: an original data file to the restoring-force CSV contract."""
    from rths_discrepancy import restoring
    if not os.path.exists(args.source):
        raise OSError(f'{args.source}: no such file')
    data = restoring.validate(restoring.convert(args.kind, args.source), source=args.source)
    restoring.write_csv(args.out, data)
    print(f"wrote {args.out}: {data['time_s'].size} rows at {data['fs']:g} Hz")
    return 0


def bench_real_cmd(args) -> int:
    """``rths bench discrepancy-real``: the restoring-force scenario on the real records."""
    from rths_common import datasets
    from rths_discrepancy import restoring
    data_dir = args.data or datasets.data_dir()
    if not data_dir or not os.path.isdir(data_dir):
        raise OSError(f'--data DIR (or {datasets.DATA_ENV}; unset: ../shared/data beside the '
                      f'repository) must name the directory holding DATA_EMPS.mat and the '
                      f'MR-damper .txt files; looked in {args.data or datasets.where()}')
    from rths_common.progress import Progress

    with Progress(len(restoring.REAL), 'real records') as bar:
        summary = restoring.run_real(data_dir, out_dir=args.reports,
                                     progress=bar.note, count=bar.report)
    tmp = f'{args.out}.tmp'
    with open(tmp, 'w') as fh:
        json.dump(summary, fh, indent=1)
    os.replace(tmp, args.out)
    for r in summary['records']:
        if 'skipped' in r:
            print(f"{r['record']}: skipped ({r['skipped']})")
            continue
        print(f"{r['record']}: {r['effect']}; held-out NRMSE {r['nrmse_before']:.4f} -> "
              f"{r['nrmse_after']:.4f} (target <= {r['nrmse_target']:.2f}: "
              f"{'met' if r['nrmse_target_met'] else 'not met'}); alignment "
              f"{r['alignment_samples']:+.2f} samples")
        if 'published_comparison' in r:
            c = r['published_comparison']
            print('  vs published: ' + ', '.join(
                f"{k} {c['fitted'][k]:.4g} ({100 * e:.1f} %)"
                for k, e in c['relative_errors'].items()))
    print(f'wrote {args.out}')
    return 0


def _io_records(paths, args, what):

    from rths_common.columns import read_columns
    from rths_discrepancy import iodisc
    recs = []
    for path in paths:
        if not os.path.exists(path):
            raise OSError(f'{what} {path}: no such file')
        cols = read_columns(path, None, keep_nan=True, min_rows=0)
        recs.append(iodisc.records_from_columns(cols, args.input, args.output, fs=args.fs,
                                                time_col=args.time,
                                                source=os.path.basename(path)))
    return recs


def _io_cmd(args) -> int:
    """``rths discrepancy --scenario io``: what the identified linear model misses."""
    from rths_discrepancy import iodisc
    if not args.input or not args.output:
        raise ValueError('the io scenario needs --input COL and at least one --output COL')
    if args.model:
        raise ValueError('--model does not apply to the io scenario: its nominal model is '
                         'the linear model identified from the records')
    train = _io_records(args.measured, args, '--measured')
    test = _io_records(args.heldout, args, '--heldout') if args.heldout else None
    from rths_common.progress import Progress

    with Progress(0, 'io discrepancy') as bar:
        res = iodisc.run(train, test, out_dir=args.out, progress=bar.note)
    print(f"effect: {res['effect']}")
    for name, p in res['per_output'].items():
        print(f"  {name}: held-out NRMSE linear {p['nrmse_baseline']:.4f} (ARX reference "
              f"{p['nrmse_reference']:.4f}) -> after {p['nrmse_after']:.4f}; named "
              f"{'+'.join(p['effects']) or 'none'}")
    print(f"wrote {args.out}/result.json, report.md and PNG plots ({res['seconds']:.1f} s)")
    return 0


def run_discrepancy_cmd(args) -> int:
    """``rths discrepancy``: run the workflow and write DIR/result.json, report.md, plots."""
    if args.scenario == 'io':
        return _io_cmd(args)
    if len(args.measured) != 1:
        raise ValueError(f'--measured: the {args.scenario} scenario reads one record; several '
                         'records go together only in the io scenario')
    if args.heldout or args.input or args.output:
        raise ValueError('--input/--output/--heldout belong to the io scenario')
    args.measured = args.measured[0]
    if args.scenario == 'restoring-force':
        return _restoring_cmd(args)

    from rths_discrepancy import models
    from rths_discrepancy.workflow import run_discrepancy
    run = None  # (numerical, bridge) parameters of an RTHS bag, for the reference re-run
    if args.scenario == 'specimen' and _is_bag(args.measured) and os.path.isdir(args.measured):
        from rths_common import bagio, runinfo
        from rths_discrepancy import rerun
        bridge = runinfo.section(bagio.run_info(args.measured), 'bridge')
        if bridge and not rerun.has_table_mass(bridge):
            from rths_numerical.specimens import specimen_of

            if args.model:
                raise ValueError(f"--model: the run's specimen {specimen_of(bridge)} is no mass "
                                 'on the table (eq. 46); drop --model, its force is analysed '
                                 'by the restoring-force scenario')
            _say(f"the run's specimen {specimen_of(bridge)} is no mass on the table (eq. 46): "
                 'its measured force is analysed by the restoring-force scenario')
            return _restoring_cmd(args)
        try:
            run = rerun.run_parameters(args.measured, args.config)
        except ValueError as err:
            _say(f'note: {err}; the nominal model is the default valve #4 and the reference '
                 'is not re-run')
    data = _read_measured(args.measured, args.scenario)
    model = models.load_model(args.scenario, args.model) if args.model else None
    if run is not None:
        if model is None:
            from rths_numerical.specimens import specimen_of

            model = rerun.run_damper_model(run[1])
            _say(f"nominal model: the run's specimen {specimen_of(run[1])} "
                 f'(m_d {model.m_d:g} kg, c_d {model.c_d:g} N s/m, k_d {model.k_d:g} N/m)')
    _say(f'rths discrepancy: {args.scenario}, {len(data["time"])} samples from {args.measured}')
    from rths_common.progress import Progress

    with Progress(0, 'candidate models') as bar:
        res = run_discrepancy(args.scenario, data, model=model, out_dir=args.out,
                              progress=bar.note, count=bar.report)
    for line in res['localization']['summary']:
        print(f'where: {line}')
    print(f"effect: {res['effect']}")
    for name, par in res['parameters'].items():
        sym, val = [(k, v) for k, v in par.items() if k != 'unit'][0]
        print(f"  {name}: {sym} = {val:.6g} {par['unit']}")
    if 'unexplained_note' in res:
        print(f"  {res['unexplained_note']}")
    print(f"held-out NRMSE: before {res['nrmse_before']:.5f}, after {res['nrmse_after']:.5f}, "
          f"noise {res['nrmse_noise']:.5f}; gap closed {res['gap_closed']:.3f}")
    print('candidates (held-out NRMSE): ' + ', '.join(
        f'{k} {v:.4f}' for k, v in sorted(res['candidates'].items(), key=lambda kv: kv[1])[:6]))
    print(f'wrote {args.out}/result.json, updated_model.yaml, report.md and PNG plots')
    if run is not None and res['effect'] not in ('none', 'unexplained'):
        _say('re-running the reference of the run with the updated specimen model')
        with Progress(3, 'reference simulations') as bar:
            cmp = rerun.compare(args.measured, models.model_from_dict('specimen',
                                                                      res['updated_model']),
                                config=args.config, nominal_model=model, progress=bar.report,
                                cache_dir=args.reference_cache)
        _write_reference(cmp, args.out)
    return 0


def _write_reference(cmp, out_dir):

    from rths_discrepancy import rerun
    for line in rerun.summary_lines(cmp):
        print(line)
    os.makedirs(out_dir, exist_ok=True)
    rerun.write(cmp, os.path.join(out_dir, 'reference.json'))
    rerun.plot(cmp, os.path.join(out_dir, 'reference.png'))
    report = os.path.join(out_dir, 'report.md')
    if os.path.isfile(report):
        with open(report, encoding='utf-8') as fh:
            text = fh.read().split(rerun.REPORT_HEADING)[0].rstrip('\n')
        from rths_discrepancy.report import _atomic_write
        _atomic_write(report, text + '\n\n' + rerun.report_section(cmp))
    print(f'wrote {out_dir}/reference.json and reference.png')


def reference_cmd(args) -> int:
    """``rths reference``: RTHS-vs-reference error with the nominal and an updated specimen."""
    from rths_discrepancy import models, rerun
    if not os.path.isdir(args.bag):
        raise OSError(f'{args.bag}: no such bag directory')
    if not os.path.isfile(args.specimen_model):
        raise OSError(f'--specimen-model {args.specimen_model}: no such file')
    from rths_common.progress import Progress

    updated = models.load_model('specimen', args.specimen_model)
    with Progress(3, 'reference simulations') as bar:
        cmp = rerun.compare(args.bag, updated, config=args.config, progress=bar.report,
                            cache_dir=args.reference_cache)
    _write_reference(cmp, args.out or os.path.join(os.path.dirname(
        os.path.abspath(args.specimen_model)), 'reference'))
    return 0


def bench_discrepancy_cmd(args) -> int:
    """``rths bench discrepancy``: self-test benchmark, prints the summary, writes JSON."""
    from rths_discrepancy import selftest
    seeds = args.seeds if args.seeds is not None else (1 if args.quick else 2)
    if seeds < 1:
        raise ValueError('--seeds must be >= 1')
    summary = selftest.run_bench(seeds=seeds, quick=args.quick, workers=args.workers,
                                 progress=_say, baselines=args.baselines, detect=args.detect)
    tmp = f'{args.out}.tmp'
    with open(tmp, 'w') as fh:
        json.dump(summary, fh, indent=1)
    os.replace(tmp, args.out)
    quick = ', quick' if args.quick else ''
    print(f"cases: {summary['cases']} ({summary['seeds']} seed(s){quick})")
    print(f"correct naming: {summary['correct_naming_percent']:.1f} % (target 100 %)")
    print(f"false effects on controls: {summary['false_effects_on_controls']} of "
          f"{summary['controls']} (target 0)")
    print(f"median gap_closed: {summary['median_gap_closed']:.3f} (target >= 0.9)")
    ok, n = summary['parameters_within_15_percent_full_strength']
    print(f'parameters within 15 % (full strength, correctly named): {ok}/{n}')
    ok, n = summary['parameters_within_15_percent_one_fifth_strength']
    print(f'parameters within 15 % (one-fifth strength, correctly named): {ok}/{n}')
    by_seed = summary.get('by_seed')
    if by_seed and len(by_seed['seeds']) > 1:
        lo, hi = by_seed['correct_naming_percent_min_max']
        glo, ghi = by_seed['median_gap_closed_min_max']
        print(f"  spread over {len(by_seed['seeds'])} seeds (rths convention, every case): "
              f'correct naming {lo:.1f}-{hi:.1f} %, median gap_closed {glo:.3f}-{ghi:.3f}')
    for conv, c in summary.get('by_convention', {}).items():
        al = ', '.join(f'{sc} {v:+.2f}' for sc, v in c['median_alignment_samples'].items())
        print(f"  convention {conv:22s}: {c['correct_naming_percent']:.1f} % of {c['cases']} "
              f"correct, {c['false_effects_on_controls']} false on controls, median "
              f'alignment (samples) {al}')
    for name, h in summary.get('heldout', {}).items():
        print(f"held-out set {name} (independent simulator): {h['named']} of {h['records']} "
              f"named (target >= {h['target']})")
    det = summary.get('detectability')
    if det:
        print(f"smallest detectable strength at {100 * det['noise']:g} % noise over "
              f"{det.get('seeds', 1)} seed(s) (of "
              f"{', '.join(f'{v:g}' for v in det['strengths'])}; the full-strength size x it):")
        for key, d in det['effects'].items():
            size = 'not detected' if d['smallest_strength'] is None else (
                f"{d['smallest_strength']:g} (size {d['smallest_size']:.3g})")
            print(f"  {key:36s} {size}; below: {', '.join(d['answers_below']) or '-'}")
        print(f"false names below the detectable size: {det['false_names_below_total']}")
    print('confusion matrix (expected -> named: count):')
    for exp, row in sorted(summary['confusion_matrix'].items()):
        print(f'  {exp:45s} ' + ', '.join(f'{k}: {v}' for k, v in sorted(row.items())))
    bl = summary.get('baselines')
    if bl:
        sd, best, nx = bl['sindy_default'], bl['sindy_best_of_sweep'], bl['narx']
        print(f"workflow: {summary['correct_naming_percent']:.1f} % correct, "
              f"{summary['false_effects_on_controls']}/{summary['controls']} false effects")
        print(f"pysindy STLSQ (threshold {sd['threshold']}, finite differences): "
              f"{sd['correct_naming_percent']:.1f} % correct, {sd['false_effects_on_controls']}/"
              f"{bl['controls']} false effects; best of sweep ({best['setting']}, tuned on "
              f"the answers): {best['correct_naming_percent']:.1f} %, "
              f"{best['false_effects_on_controls']} false")
        ex = nx['examples'][0]['terms'] if nx['examples'] else []
        med = nx['median_free_run_nrmse']
        print(f"sysidentpy FROLS NARX: names no effect (0 %); median free-run NRMSE "
              f"{med if med is None else round(med, 3)}; e.g. terms {', '.join(ex)}")
    print(f"targets met: {summary['targets_met']}; wall time {summary['wall_time_s']:.0f} s; "
          f'wrote {args.out}')
    return 0


def register(commands, benches):
    """Add this package's ``rths <command>`` and ``rths bench <name>`` parsers."""
    p = commands.add_parser(
        'discrepancy',
        help='find where a model and a measurement disagree, name the missing effect, add it',
        description='Re-simulate the nominal model with the measured input, localise the '
                    'residual in time, frequency and state, fit a library of physical effects '
                    '(coulomb_friction, viscous_damping_error, stiffness_error, cubic_stiffness, '
                    'mass_error, backlash, time_delay, velocity_saturation, sensor_bias, '
                    'force_offset (specimen) and '
                    'pairs) on training blocks, score them on held-out blocks and name the '
                    'winner (or none / unexplained). Prints the localisation, the effect and '
                    'its parameters and the held-out NRMSE before/after; writes '
                    'DIR/result.json, DIR/updated_model.yaml (loadable with --model), '
                    'DIR/report.md and PNG plots.')
    p.add_argument('--scenario', required=True,
                   choices=('specimen', 'actuator', 'restoring-force', 'io'),
                   help='specimen: CSV columns time, base_accel, rel_disp, force (DTM, eq. 46); '
                        'actuator: CSV columns time, command, measured; restoring-force: a '
                        'measured specimen, CSV columns time_s, displacement_m, force_N '
                        '[, velocity_m_s], nominal m a + c v + k x fitted, later part held out; '
                        'io: any input-output record (--input, --output), any rate and units, '
                        'nominal = the identified linear model, effects named from what it '
                        'misses (saturation, static_output_nonlinearity, '
                        'amplitude_dependent_stiffness/damping across levels, cubic_stiffness, '
                        'hysteresis, backlash, coulomb_friction)')
    p.add_argument('--measured', required=True, nargs='+', metavar='CSV|BAG',
                   help='measured record: CSV with a header row (uniform sampling) or a bag '
                        'recorded by rths; the io scenario takes several records of one '
                        'system (e.g. excitation levels: level dependence is the signature '
                        'of most joint nonlinearities)')
    p.add_argument('--input', metavar='COL', help='io: the input column (e.g. a force, a '
                                                  'voltage)')
    p.add_argument('--output', action='append', metavar='COL',
                   help='io: an output column (repeat for several outputs)')
    p.add_argument('--time', metavar='COL', help='io: the time column [s] (or give --fs)')
    p.add_argument('--fs', type=float, metavar='HZ',
                   help='io: sample rate when the records have no time column')
    p.add_argument('--heldout', nargs='+', metavar='CSV',
                   help='io: records kept out of every fit and choice, on which the gap '
                        'before/after is measured (default: the later 40 %% of each record)')
    p.add_argument('--model', metavar='MODEL.yaml',
                   help='nominal model YAML (default: Table 4 valve #4 DTM / Table 1 3-pole '
                        'actuator); layouts in rths_discrepancy.models')
    p.add_argument('--config', metavar='DIR',
                   help='params directory the run was launched with (numerical.yaml, '
                        'bridge.yaml), used only for a bag whose run information lacks the '
                        "run's parameters (a recorder started by hand); bags of rths launch "
                        '--bag and rths run carry them')
    p.add_argument('--reference-cache', metavar='DIR',
                   help='directory sharing the reference simulations among runs with the same '
                        'numerical side and specimen model (a study, a benchmark): each is '
                        'simulated once, keyed by what it depends on; use a new directory '
                        'after changing the code (default: no cache)')
    p.add_argument('--out', required=True, metavar='DIR', help='output directory')
    p.set_defaults(func=run_discrepancy_cmd)

    c = commands.add_parser(
        'discrepancy-csv',
        help='convert an original real-data file to the restoring-force CSV contract',
        description='Write the restoring-force CSV (time_s, displacement_m, force_N '
                    '[, velocity_m_s]) of an original data file: emps = DATA_EMPS.mat of the '
                    'EMPS benchmark (force = gtau * vir, position qm); mr-damper = a '
                    'preprocessed MR-damper sinusoid .txt (t [s], x [mm], v [mm/s], F [N]).')
    c.add_argument('kind', choices=('emps', 'mr-damper'), help='layout of the source file')
    c.add_argument('source', help='original data file')
    c.add_argument('--out', required=True, metavar='FILE.csv', help='CSV to write')
    c.set_defaults(func=csv_cmd)

    r = commands.add_parser(
        'reference',
        help='re-run the reference of an RTHS bag with an updated specimen model',
        description='Re-run the reference of the RTHS recorded in BAG (the same numerical '
                    'substructure coupled to a numerical DTM on a perfect table) with the '
                    "run's nominal Table 4 damper and with --specimen-model (e.g. the "
                    'updated_model.yaml of rths discrepancy: its loop effects such as '
                    'coulomb_friction are simulated), and print the relative RMS error of the '
                    "RTHS 2nd-floor displacement against each (and against rths review's "
                    'linear whole-numerical reference). Writes reference.json and '
                    'reference.png to --out.')
    r.add_argument('bag', help='RTHS bag directory (of rths launch --bag or rths run)')
    r.add_argument('--specimen-model', required=True, metavar='MODEL.yaml',
                   help='specimen model YAML (kind: dtm, m_d, c_d, k_d, effects)')
    r.add_argument('--config', metavar='DIR',
                   help="params directory of the launch, only for a bag whose run information "
                        "lacks the run's parameters")
    r.add_argument('--reference-cache', metavar='DIR',
                   help='directory sharing the reference simulations among runs with the same '
                        'numerical side and specimen model (a study, a benchmark): each is '
                        'simulated once, keyed by what it depends on; use a new directory '
                        'after changing the code (default: no cache)')
    r.add_argument('--out', metavar='DIR',
                   help='output directory (default: reference/ next to the model file)')
    r.set_defaults(func=reference_cmd)

    b = benches.add_parser(
        'discrepancy',
        help='self-test of the discrepancy workflow on synthetic records with hidden effects',
        description='Generate synthetic specimen and actuator records with each effect hidden '
                    '(full and one-fifth strength), pairs, Stribeck friction (form mismatch), a '
                    'first-order lag (no candidate) and clean controls, with noise and several '
                    'seeds, under the rths DAQ timing convention and three others (input held '
                    'or interpolated over the step, output read at the other end of the step, '
                    'one more converter step: these must be named none); then two held-out sets '
                    'from an independent simulator (14 and 12 records). Run the workflow on '
                    'each and print the confusion matrix, the percentage of correct naming, '
                    'false effects on the controls, the median gap_closed and the held-out '
                    'counts; write everything to --out as JSON. Progress goes to stderr.')
    b.add_argument('--out', required=True, metavar='FILE.json', help='JSON result file')
    b.add_argument('--seeds', type=int, default=None,
                   help='random seeds per case under the rths convention and of the --detect '
                        'sweep (default 2, with --quick 1); one seed under the other conventions; '
                        'the summary gives the spread over the seeds')
    b.add_argument('--quick', action='store_true',
                   help='full-strength effects only, two pairs, controls under the other '
                        'conventions, 8 s records, one seed, no held-out sets')
    b.add_argument('--workers', type=int, default=2, help='worker processes (default 2)')
    b.add_argument('--detect', action='store_true',
                   help='also sweep every effect down to 1 %% of its full-strength size and '
                        'report the smallest detectable size (never another effect below it)')
    b.add_argument('--baselines', action='store_true',
                   help='also run pysindy (SINDy, STLSQ) and sysidentpy (FROLS NARX) on every '
                        'record and compare (needs pip install pysindy sysidentpy)')
    b.set_defaults(func=bench_discrepancy_cmd)

    g = benches.add_parser(
        'discrepancy-real',
        help='restoring-force scenario on the real EMPS and MR-damper records',
        description='Run rths discrepancy --scenario restoring-force on the EMPS record '
                    '(DATA_EMPS.mat) and three MR-damper sinusoid tests (10mm1Hz1A, '
                    '25mm0x25Hz0x5A, 2mm5Hz1A) found under --data; print and save the named '
                    'effects, the held-out NRMSE against the targets (EMPS <= 5 %, MR <= 8 %) '
                    'and the EMPS parameters against the published ones. The data are not in '
                    'the repository (README: real data).')
    g.add_argument('--data', metavar='DIR', help='directory with the original files (default: '
                                                 '$RTHS_DATA_DIR; unset: ../shared/data beside '
                                                 'the repository)')
    g.add_argument('--out', required=True, metavar='FILE.json', help='JSON result file')
    g.add_argument('--reports', metavar='DIR', help='also write each record\'s report and plots')
    g.set_defaults(func=bench_real_cmd)
