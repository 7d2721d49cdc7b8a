"""``rths bench discrepancy-v3``: the io scenario on the public development data sets.

Per data set (cascaded tanks, Bouc-Wen, F-16 ground vibration test; loaders, protocols
and published figures in :mod:`rths_discrepancy.devsets`): the linear baseline's error
against the published linear reference, the named effect against the paper's, the
error after against the published nonlinear references, and the seconds it took; then the
timing run: the io scenario, unattended, on one 10^5-sample F-16 record (levels 5 and 7
back to back, three accelerations) against the issue's 2 minutes.  The
restoring-force records (EMPS, MR damper) are benchmarked by ``rths bench
discrepancy-real``.
"""

import json
import os
import sys
import time

# Imports of the commands' code sit in the command functions: rths imports this module
# to build its parser, and every rths command would pay for SciPy, matplotlib and ROS.


def _say(text):
    from rths_common.progress import mode
    if mode(sys.stderr) != 'off':
        print(text, file=sys.stderr, flush=True)


def bench_cmd(args) -> int:
    """Run the development sets, print one line each, write the JSON."""
    from rths_discrepancy import devsets
    root = devsets.data_dir(args.data)
    names = args.sets or list(devsets.LOADERS)
    for n in names:
        if n not in devsets.LOADERS:
            raise ValueError(f'--sets: unknown data set {n!r}; use {", ".join(devsets.LOADERS)}')
    load = os.getloadavg()
    t0 = time.perf_counter()
    rows = devsets.run_all(root, names, out_dir=args.reports, progress=_say)
    summary = {'data_dir': os.path.abspath(root), 'sets': rows}
    if not args.no_timing:
        _say(f'timing: the io scenario on a {devsets.TIMING_SAMPLES}-sample record')
        summary['timing'] = devsets.run_timing(root, progress=_say)
    summary.update(load_average_1_5_15_at_start=list(load),
                   load_average_1_5_15_at_end=list(os.getloadavg()),
                   wall_time_s=time.perf_counter() - t0)
    tmp = f'{args.out}.tmp'
    with open(tmp, 'w') as fh:
        json.dump(summary, fh, indent=1, default=float)
    os.replace(tmp, args.out)
    for r in rows:
        lin = ('no published linear figure' if r['baseline_vs_published_linear'] is None else
               f"{r['baseline_vs_published_linear']:.2f} x published linear")
        nl = r['after_vs_published_nonlinear']
        nl = 'no published nonlinear figure' if not nl else ', '.join(
            f'{v:.2f} x {k.split(" (")[0]}' for k, v in nl.items())
        print(f"{r['data_set']}: baseline RMSE {r['baseline_rmse']:.4g} ({lin}; ARX reference "
              f"{r['arx_reference_rmse']:.4g}); named {r['effect']} (paper: "
              f"{r['paper_names']}: {'match' if r['named_effect_matches_paper'] else 'no match'}"
              f"); after {r['after_rmse']:.4g} ({nl}); {r['seconds']:.0f} s")
    tm = summary.get('timing')
    if tm:
        print(f"timing: {tm['samples']} samples x {tm['outputs']} outputs ({tm['record']}) in "
              f"{tm['seconds']:.0f} s (target <= {tm['target_s']:.0f} s: "
              f"{'met' if tm['met'] else 'not met'}; load {os.getloadavg()[0]:.1f})")
    print(f'wrote {args.out}')
    return 0


def register(commands, benches):
    """Add ``rths bench discrepancy-v3``."""
    b = benches.add_parser(
        'discrepancy-v3',
        help='io discrepancy scenario on the public development data sets vs published figures',
        description='Run rths discrepancy --scenario io on the cascaded tanks, the Bouc-Wen '
                    'benchmark and the F-16 ground vibration test (found under --data or '
                    '$RTHS_DATA_DIR, never in the repository) with each benchmark\'s own '
                    'estimation/test protocol; print and save per data set the baseline '
                    'error against the published linear reference, the named effect against '
                    'the paper\'s, the error after against published nonlinear references, '
                    'and the seconds; then time the scenario, unattended, on a 10^5-sample '
                    'F-16 record (target <= 2 minutes).')
    b.add_argument('--out', required=True, metavar='FILE.json', help='JSON result file')
    b.add_argument('--data', metavar='DIR', help='shared data directory (default: '
                                                 '$RTHS_DATA_DIR, else ../shared/data)')
    b.add_argument('--sets', nargs='+', metavar='NAME',
                   help='only these data sets (cascaded_tanks, bouc_wen, f16gvt)')
    b.add_argument('--reports', metavar='DIR', help="also write each set's report and plots")
    b.add_argument('--no-timing', action='store_true',
                   help='skip the timing run (the io scenario, unattended, on a 10^5-sample '
                        'F-16 record; target <= 2 minutes)')
    b.set_defaults(func=bench_cmd)
