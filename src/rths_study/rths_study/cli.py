"""``rths study run``, ``rths bench study``, and the benchmark's many draws through the runner.

* ``rths study run SPEC.yaml --out DIR [--scheduler tcp://HOST:8786] [--workers N]``:
  check the SPEC, run what ``DIR`` does not hold yet, write the report.
* ``rths bench study --out F.json``: :mod:`.bench`.
* ``rths bench rths-benchmark --draws N``: from :data:`DRAWS_VIA_RUNNER` draws (or with
  ``--scheduler``/``--workers``) the perturbed plants run through the study runner, into
  ``OUT/study``; the four nominal cases run in this process as before.  (The command is
  ``rths_bench``'s; this module, above it, adds the two options and the route in
  :func:`extend`, which ``rths`` calls after every package has registered its commands.)
"""

import argparse
import functools
import importlib
import os

# Imports of the commands' code sit in the command functions: rths imports this module
# to build its parser, and every rths command would pay for SciPy, matplotlib and ROS.

#: From this many perturbed draws, ``rths bench rths-benchmark`` uses the study runner:
#: one vectorised batch of N runs holds ~2.4 MB per run and second of record (1000
#: draws of El Centro: ~4 GB), the runner's chunks a few hundred MB per worker.
DRAWS_VIA_RUNNER = 200


def add_cluster_arguments(p):
    """``--scheduler`` and ``--workers``."""
    p.add_argument('--scheduler', default=None, metavar='tcp://HOST:8786',
                   help='address of a running Dask scheduler (`dask scheduler` on one lab '
                        'PC, `dask worker tcp://HOST:8786` on each; docs/studies.md); '
                        'default: a local cluster on this machine')
    p.add_argument('--workers', type=int, default=None, metavar='N',
                   help='local cluster: N worker processes (default: the cores); with '
                        '--scheduler: wait until N workers have joined')


def register(commands, benches):
    """Add ``rths study run`` and ``rths bench study``."""
    studies = _study_subcommands(commands)
    p = studies.add_parser(
        'run', help='run a study SPEC (grid, random draws or list) on a Dask cluster',
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description='Run every run of SPEC.yaml (each parameter point with each controller '
                    'and record) on a Dask cluster, one row per run in DIR/runs (Parquet), '
                    'then write DIR/summary.json, plots and DIR/report.html. Rerunning into '
                    'the same DIR skips the runs it holds; Ctrl-C keeps every finished row. '
                    'Exit code 1 when a run failed (its error is in the table and the '
                    'log), 2 for a bad SPEC.\n\nScenarios (scenario.kind):\n'
                    + _scenario_lines()
                    + '\nSPEC examples: config/studies/*.yaml; fields: docs/studies.md.')
    p.add_argument('spec', metavar='SPEC.yaml', help='the study SPEC')
    p.add_argument('--out', required=True, metavar='DIR', help='study directory')
    add_cluster_arguments(p)
    p.add_argument('--retry-failed', action='store_true',
                   help='run again the runs DIR holds as failed')
    p.add_argument('--check', action='store_true',
                   help='check the SPEC and print what would run; start nothing')
    p.add_argument('--no-plots', action='store_true', help='summary.json only')
    p.set_defaults(func=cmd_run)

    from . import bench
    bench.register(benches)


def extend(commands, benches):
    """Route the benchmark's many draws and the seed's DTM studies to the runner.

    ``rths`` calls this after every package has registered its commands.
    """
    _route_benchmark(benches)
    _route_dtm_studies(_study_subcommands(commands))


# ------------------------------------- rths study dtm-tuning / building-frequency
def _route_dtm_studies(studies):
    """Compute the grids of ``rths study dtm-tuning`` / ``building-frequency`` on the runner.

    The commands keep their options and outputs (JSON, PNG): their criteria come from
    the study runner (the SPECs of ``config/studies/dtm_tuning.yaml`` and
    ``building_frequency.yaml``), one run per grid point, the table in ``OUT/runs_*``
    (rerunning the command skips the points it holds).
    """
    for name in ('dtm-tuning', 'building-frequency'):
        parser = studies.choices.get(name)
        if parser is None:
            raise RuntimeError(f'rths_study.cli: rths study {name} is not registered; rebuild '
                               'the workspace (make setup) so that rths_numerical is installed')
        add_cluster_arguments(parser)
        direct = parser.get_default('func')
        grid = _dtm_tuning_grid if name == 'dtm-tuning' else _building_frequency_grid
        parser.set_defaults(func=lambda args, direct=direct, grid=grid: direct(
            args, surfaces=functools.partial(grid, args)))
        parser.description += (' The grid runs on the study runner (rths study run; a local '
                               'Dask cluster, or --scheduler), its table in OUT/runs_*.')


def _dtm_tuning_grid(args, fn_hz, zetas) -> dict:
    """Return the dtm-tuning criteria of the grid ``fn_hz`` x ``zetas`` (the runner)."""
    raw = {'study': 'dtm-tuning',
           'scenario': {'kind': 'dtm-tuning', 'building': 'building2story',
                        'mass_ratio': args.mass_ratio, 'f1_hz': args.f1_hz,
                        'duration_s': args.duration_s, 'fs_hz': args.fs_hz,
                        'signal_seed': args.seed},
           'parameters': {'grid': {'fn_hz': list(fn_hz), 'zeta': list(zetas)}}}
    return _grid(args, raw, os.path.join(args.out, 'runs_dtm_tuning'), ('fn_hz', 'zeta'))


def _building_frequency_grid(args, damper, f1_hz, mass_ratios) -> dict:
    """Return the building-frequency criteria of one damper's grid (the runner)."""
    raw = {'study': f'building-frequency-{damper}',
           'scenario': {'kind': 'building-frequency', 'building': args.building,
                        'damper': damper, 'scale': args.scale, 'fs_hz': args.fs_hz},
           'parameters': {'grid': {'f1_hz': list(f1_hz), 'mass_ratio': list(mass_ratios)}},
           'records': [args.record]}
    return _grid(args, raw, os.path.join(args.out, f'runs_building_frequency_{damper}'),
                 ('f1_hz', 'mass_ratio'))


def _grid(args, raw, study_dir, axes) -> dict:
    """Run a two-axis grid SPEC into ``study_dir``; return each metric as a 2-D array."""
    import numpy as np

    from .spec import check_spec
    from .store import Store, schema_of
    spec = check_spec({**raw, 'parameters': {'grid': {
        a: [float(v) for v in values] for a, values in raw['parameters']['grid'].items()}}},
        f'rths study {raw["scenario"]["kind"]}')
    code = run_and_report(spec, study_dir, args.scheduler, args.workers, plots=False)
    if code:
        raise ValueError(f'grid points failed (their errors: {study_dir}/study.log); fix the '
                         'cause and rerun: the points already done are skipped')
    first, second = (spec.axes[a] for a in axes)
    where = {(row[axes[0]], row[axes[1]]): row
             for row in Store(study_dir, schema_of(spec)).table().to_pylist()}
    return {m: np.array([[where[(x, y)][m] for y in second] for x in first])
            for m in spec.metrics}


def _study_subcommands(commands):
    """Return the sub-commands of ``rths study`` (rths_numerical adds the command)."""
    if 'study' not in commands.choices:
        commands.add_parser('study', help='parameter studies').add_subparsers(
            dest='study', metavar='STUDY').required = True
    parser = commands.choices['study']
    return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))


def _scenario_lines() -> str:
    from .scenarios import REGISTRY
    lines = []
    for kind, target in REGISTRY.items():
        module, name = target.split(':')
        lines.append(f'  {kind:20s}{_summary_of(module, name)}')
    return '\n'.join(lines) + '\n'


def _summary_of(module, name) -> str:
    try:
        return getattr(importlib.import_module(module), name).summary
    except ImportError as err:          # a scenario whose package is missing here
        return f'(unavailable: {err})'


def cmd_run(args) -> int:
    """Run ``rths study run``."""
    from .spec import load_spec
    spec = load_spec(args.spec)
    spec.source = args.spec
    runs = spec.runs()
    print(f'{spec.study}: scenario {spec.kind}, {len(spec.points)} parameter points x '
          f'{len(spec.controllers)} controllers x {len(spec.records)} records = {len(runs)} '
          f'runs, {spec.chunk} per task')
    if args.check:
        return 0
    return run_and_report(spec, args.out, args.scheduler, args.workers, args.retry_failed,
                          plots=not args.no_plots)


def run_and_report(spec, out, scheduler=None, workers=None, retry_failed=False,
                   plots=True) -> int:
    """Run the study, then write the report (also after Ctrl-C, without plots)."""
    from .report import write_report
    from .runner import run_study
    from .store import Store, schema_of
    try:
        stats = run_study(spec, out, scheduler, workers, retry_failed)
    except KeyboardInterrupt:
        write_report(spec, Store(out, schema_of(spec)), {'interrupted': True}, plots=False)
        print(f'interrupted: the finished runs are in {out}/runs; rerun the same command to '
              'continue')
        raise
    files = write_report(spec, Store(out, schema_of(spec)), stats, plots=plots)
    print(f"{stats['ran']} runs done ({stats['ok']} ok, {stats['errors']} failed), "
          f"{stats['skipped']} already in {out}; {stats['wall_s']:.1f} s on "
          f"{stats['workers']} workers")
    for f in files:
        print(f'wrote {f}')
    table = Store(out, schema_of(spec)).table()
    failed = sum(1 for s in table.column('status').to_pylist() if s != 'ok')
    if failed:
        print(f'{failed} runs failed: their errors are in {out}/study.log and the table')
    return 1 if failed else 0


# ------------------------------------------------- rths bench rths-benchmark --draws N
def _route_benchmark(benches):
    """Give ``rths bench rths-benchmark`` the cluster options and the runner for big N."""
    parser = benches.choices.get('rths-benchmark')
    if parser is None:
        raise RuntimeError('rths_study.cli: rths bench rths-benchmark is not registered; '
                           'rebuild the workspace (make setup) so that rths_bench is installed')
    add_cluster_arguments(parser)
    direct = parser.get_default('func')
    parser.set_defaults(func=lambda args: _benchmark(args, direct))
    for action in parser._actions:
        if action.dest == 'draws':
            action.help += (f'; from {DRAWS_VIA_RUNNER} draws (or with --scheduler/--workers)'
                            ' they run through the study runner (rths study run) into '
                            'OUT/study, on a local or remote Dask cluster')


def _benchmark(args, direct) -> int:
    """Run the benchmark: directly, or its draws through the study runner."""
    if args.via != 'loop' or not (args.draws >= DRAWS_VIA_RUNNER or args.scheduler
                                  or args.workers):
        return direct(args)

    # lazy: optional dependency (threadpoolctl)
    from threadpoolctl import threadpool_limits

    from rths_bench import rths_benchmark as rb
    spec = benchmark_spec(args)
    print(f'rths-benchmark: {args.draws} perturbed plants through the study runner '
          f'({len(spec.runs())} runs) into {args.out}/study')
    with threadpool_limits(limits=1):       # the same FIR design as on the workers
        summary = rb.run_benchmark(args.controller, args.record, 0, args.seed,
                                   args.duration or None, args.data_dir, rb.fir_options(args),
                                   rb.parse_cases(args.cases))
    study_dir = os.path.join(args.out, 'study')
    run_and_report(spec, study_dir, args.scheduler, args.workers, plots=not args.no_plots)
    from .store import Store, schema_of
    rows = Store(study_dir, schema_of(spec)).table().to_pylist()
    stable = [r for r in rows if r['status'] == 'ok' and not r['unstable']]
    unstable = sum(1 for r in rows if r['status'] != 'ok' or r['unstable'])
    summary['perturbed'] = rb.perturbed_summary(args.draws, stable, unstable)
    summary['draws'] = [rb.draw_record(p) for p in rb.perturbed_draws(args.draws, args.seed)]
    summary['settings']['draws_via'] = f'study runner: {study_dir}'
    return rb.print_outputs(summary, args)


def benchmark_spec(args):
    """Return the SPEC of ``rths bench rths-benchmark``'s draws (the command's own)."""
    from rths_bench import rths_benchmark as rb

    from .spec import check_spec
    draws = [{k: float(getattr(p, k)) for k in ('b1', 'b2', 'a3', 'k_e')}
             for p in rb.perturbed_draws(args.draws, args.seed)]
    fir = rb.fir_options(args)
    raw = {'study': f'rths-benchmark-{args.controller}-draws',
           'scenario': {'kind': 'benchmark', 'case': '1', 'duration_s': args.duration or 0.0,
                        'data_dir': args.data_dir, 'taps': fir['n_taps'],
                        'fc_hz': fir['fc_hz'], 'scheme': fir['scheme'],
                        'epsilon': fir['epsilon'], 'lowpass_hz': fir['lowpass_hz']},
           'parameters': {'list': draws}, 'controllers': [args.controller],
           'records': [args.record], 'seed': args.seed}
    return check_spec(raw, 'rths bench rths-benchmark')
