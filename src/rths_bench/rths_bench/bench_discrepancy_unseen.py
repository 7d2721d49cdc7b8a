"""``rths bench discrepancy-unseen``: the discrepancy workflow on records it has never seen.

The battery of :mod:`rths_discrepancy.unseen` (a third simulator, its own physics code:
analytic displacement paths and DOP853-integrated shaker tests, odd rates, volts, mm,
kN and counts with offsets and drifts, 0.1-3 % noise, multisine, swept, stepped and
random excitations), drawn from ``--seed``: per case the name given against the
expected one (at most one extra name), the gap closed against what the true model
closes (at least half), the seconds; per effect the cases passed.
"""

import json
import os
import sys
import time

# Imports of the commands' code sit in the command functions: rths imports this module
# to build its parser, and every rths command would pay for SciPy and ROS.

#: The seed of the judged battery, fixed after the method was settled (the
#: development seed was 1).
SEED = 20261127


def _say(text):
    from rths_common.progress import mode
    if mode(sys.stderr) != 'off':
        print(text, file=sys.stderr, flush=True)


def bench_cmd(args) -> int:
    """Run the battery, print one line per case and the per-effect table, write the JSON."""
    from rths_discrepancy import unseen
    cases = unseen.battery(args.seed, per_effect=args.per_effect)
    if args.cases:
        known = [c['name'] for c in cases]
        for k in args.cases:
            if k not in known:
                raise ValueError(f'--cases: no case {k!r}; cases are {", ".join(known)}')
        cases = [c for c in cases if c['name'] in args.cases]
    load = os.getloadavg()
    t0 = time.perf_counter()
    rows = []
    for i, c in enumerate(cases):
        _say(f"[{i + 1}/{len(cases)}] {c['name']}: {c['excitation']} at {c['fs']:g} Hz, "
             f"{c['n']} samples, {c['units']}, noise {100 * c['noise']:.2f} %")
        r = unseen.run_case(c)
        rows.append(r)
        ratio = r['gap_closed_vs_true']
        print(f"{r['case']}: expected {r['expected']}, named {r['named']}; NRMSE "
              f"{r['nrmse_before']:.4f} -> {r['nrmse_after']:.4f} (true model "
              f"{r['nrmse_true_model']:.4f}; gap {'n/a' if ratio is None else f'{ratio:.2f}'}"
              f" of the true model's); {'pass' if r['passed'] else 'FAIL'}; "
              f"{r['seconds']:.0f} s", flush=True)
    table = unseen.summarise(rows)
    summary = {'seed': args.seed, 'development_seed': 1, 'cases': len(rows),
               'passed': sum(r['passed'] for r in rows), 'per_effect': table,
               'max_case_seconds': max((r['seconds'] for r in rows), default=0.0),
               'rows': rows, 'load_average_1_5_15_at_start': list(load),
               'load_average_1_5_15_at_end': list(os.getloadavg()),
               'wall_time_s': time.perf_counter() - t0}
    tmp = f'{args.out}.tmp'
    with open(tmp, 'w') as fh:
        json.dump(summary, fh, indent=1, default=float)
    os.replace(tmp, args.out)
    for k, e in table.items():
        print(f"{k}: {e['passed']}/{e['cases']} (expected {e['expected']}; named "
              f"{', '.join(e['named'])})")
    print(f"passed {summary['passed']}/{summary['cases']} (seed {args.seed}); "
          f"slowest case {summary['max_case_seconds']:.0f} s; wrote {args.out}")
    return 0


def register(commands, benches):
    """Add ``rths bench discrepancy-unseen``."""
    b = benches.add_parser(
        'discrepancy-unseen',
        help='discrepancy workflow on a battery of unseen records (odd rates, units, noise)',
        description='Generate records the workflow has never seen with an independent '
                    'simulator (restoring-force and input-output; rates 250-5000 Hz, '
                    'volts, mm, kN or counts with offsets and drifts, 0.1-3 %% noise, '
                    'multisine, swept, stepped and random excitations; cubic stiffness, '
                    'backlash, Coulomb and Stribeck friction, Bouc-Wen hysteresis, '
                    'quadratic damping, saturation and linear controls), run the workflow '
                    'on each and judge it: the expected name given with at most one extra '
                    'name, the gap closed at least half of what the true model closes; '
                    'print and save per case and per effect.')
    b.add_argument('--out', required=True, metavar='FILE.json', help='JSON result file')
    b.add_argument('--seed', type=int, default=SEED,
                   help=f'seed of the battery (default {SEED}, fixed after the method was '
                        'settled; the development seed was 1)')
    b.add_argument('--per-effect', type=int, default=2, metavar='N',
                   help='restoring-force records per effect (default 2; the linear '
                        'controls get one more)')
    b.add_argument('--cases', nargs='+', metavar='NAME',
                   help='only these cases (names as printed, e.g. rf_bouc_wen_0)')
    b.set_defaults(func=bench_cmd)
