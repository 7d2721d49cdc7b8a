"""``rths bench study``: the study runner's speed-up, worker loss, serial equality and resume.

One study of benchmark runs (``--runs`` runs: perturbed plants of case 1 with the
``example`` and ``fir`` controllers, ``--duration`` s of the public Imperial Valley record
scaled to El Centro's PGA, ``--chunk`` runs per task) runs four times, each on a fresh
local cluster, each timed from the first submission to the last row on disk (cluster
start-up is not counted, the workers' first imports and FIR design are):

1. one worker (``serial_s``); 2. ``--workers`` workers (``parallel_s``, ``speedup``);
3. ``--workers`` workers with one worker process killed (SIGKILL) while both are busy:
   ``tasks_lost_after_worker_kill`` counts runs without an ok row afterwards;
4. the first study rerun into its own directory: ``resumed_skipped`` runs skipped.

``identical_to_serial``: the rows of 2 and 3 equal those of 1 bit for bit (every column
but seconds, worker and finished).  The JSON holds exactly ``tasks, workers, serial_s,
parallel_s, speedup, tasks_lost_after_worker_kill, identical_to_serial,
resumed_skipped``; the load average and the per-run cost are printed.
"""

import json
import math
import os
import signal
import tempfile
import time

from rths_actuator_bridge.silva2020 import SIGMA, Silva2020Params

from .runner import run_study
from .spec import check_spec
from .store import CIRCUMSTANCE_COLUMNS, Store, schema_of

#: Scale of the Imperial Valley 1979 record (gmspy, PGA 0.315 g) that gives El Centro
#: 1940 x 0.4's PGA (0.349 g x 0.4 = 0.14 g), the benchmark's default excitation.
IMPERIAL_VALLEY_SCALE = 0.44


def bench_spec(runs: int, duration_s: float, chunk: int, seed: int = 2020):
    """Return the bench's study: ``runs`` benchmark runs, half per controller."""
    nominal = Silva2020Params()
    draws = {k: {'normal': {'mean': float(getattr(nominal, k)), 'std': float(s)}}
             for k, s in SIGMA.items()}
    return check_spec({
        'study': 'bench-study',
        'scenario': {'kind': 'benchmark', 'duration_s': duration_s,
                     'scale': IMPERIAL_VALLEY_SCALE},
        'parameters': {'random': {'n': int(math.ceil(runs / 2)), 'seed': seed,
                                  'draws': draws}},
        'controllers': ['example', 'fir'], 'records': ['gmspy:imperial_valley'],
        'seed': seed, 'execution': {'chunk': chunk}}, 'rths bench study')


def comparable(table) -> list:
    """Rows without the columns that tell how a run went (seconds, worker, finished)."""
    keep = [n for n in table.column_names if n not in CIRCUMSTANCE_COLUMNS]
    return [tuple(_same(v) for v in row.values())
            for row in table.select(keep).to_pylist()]


def _same(value):
    """Make NaN equal NaN (the metrics of a failed or unstable run)."""
    return 'nan' if isinstance(value, float) and math.isnan(value) else value


class WorkerKiller:
    """``on_result`` callback: SIGKILL one busy worker process once ``after`` runs are done."""

    def __init__(self, after: int):
        self.after = after
        self.killed = None

    def __call__(self, client, done, total):
        """Kill a worker that is processing a task (its nanny starts a new one)."""
        if self.killed or done < self.after:
            return
        busy = [addr for addr, keys in client.processing().items() if keys]
        if not busy:
            return
        pids = client.run(os.getpid, workers=[busy[0]])
        self.killed = (busy[0], pids[busy[0]])
        os.kill(pids[busy[0]], signal.SIGKILL)


def run_bench(runs=200, workers=2, duration_s=10.0, chunk=10, work_dir=None, log=print,
              spec=None) -> dict:
    """Run the four studies (module doc) of :func:`bench_spec` or ``spec``; return the JSON."""
    spec = spec or bench_spec(runs, duration_s, chunk)
    n = len(spec.runs())
    root = work_dir or tempfile.mkdtemp(prefix='rths-bench-study-')
    dirs = {name: os.path.join(root, name) for name in ('serial', 'parallel', 'killed')}
    log(f'bench study: {n} {spec.kind} runs ({spec.chunk} per task) in {root}; load '
        f'average {os.getloadavg()[0]:.2f}')
    serial = run_study(spec, dirs['serial'], workers=1, label='serial (1 worker)')
    parallel = run_study(spec, dirs['parallel'], workers=workers,
                         label=f'parallel ({workers} workers)')
    killer = WorkerKiller(after=spec.chunk)
    run_study(spec, dirs['killed'], workers=workers, on_result=killer,
              label=f'{workers} workers, one killed')
    resumed = run_study(spec, dirs['serial'], workers=1, label='rerun')
    tables = {name: Store(d, schema_of(spec)).table() for name, d in dirs.items()}
    ok_killed = sum(1 for s in tables['killed'].column('status').to_pylist() if s == 'ok')
    reference = comparable(tables['serial'])
    result = {
        'tasks': n, 'workers': workers,
        'serial_s': round(serial['wall_s'], 3), 'parallel_s': round(parallel['wall_s'], 3),
        'speedup': round(serial['wall_s'] / parallel['wall_s'], 3),
        'tasks_lost_after_worker_kill': n - ok_killed,
        'identical_to_serial': bool(len(reference) == n
                                    and comparable(tables['parallel']) == reference
                                    and comparable(tables['killed']) == reference),
        'resumed_skipped': resumed['skipped'] if resumed['ran'] == 0 else 0,
    }
    log(f'killed worker: {killer.killed[0]} (pid {killer.killed[1]})' if killer.killed
        else 'killed worker: none (no worker was busy when the kill was due)')
    log(f'per run: {serial["wall_s"] / n * 1000:.1f} ms on one worker; failed runs: serial '
        f'{serial["errors"]}, parallel {parallel["errors"]}; load average now '
        f'{os.getloadavg()[0]:.2f} (1 min), {os.cpu_count()} cores')
    return result


def cmd_bench(args) -> int:
    """Run ``rths bench study``."""
    if args.runs < 2 or args.workers < 2:
        raise ValueError('--runs and --workers must be >= 2')
    t0 = time.perf_counter()
    result = run_bench(args.runs, args.workers, args.duration, args.chunk, args.work_dir)
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    with open(args.out, 'w') as fh:
        json.dump(result, fh, indent=1)
        fh.write('\n')
    print(json.dumps(result, indent=1))
    print(f'wrote {args.out} ({time.perf_counter() - t0:.0f} s in all)')
    return 0


def register(benches):
    """Add ``rths bench study``."""
    p = benches.add_parser(
        'study', help='study runner: speed-up on 2 workers, a killed worker, resume',
        description=__doc__.split('\n\n', 1)[1])
    p.add_argument('--out', required=True, help='JSON file')
    p.add_argument('--runs', type=int, default=200, help='benchmark runs (default 200)')
    p.add_argument('--workers', type=int, default=2, help='parallel workers (default 2)')
    p.add_argument('--duration', type=float, default=10.0,
                   help='seconds of record per run (default 10)')
    p.add_argument('--chunk', type=int, default=10, help='runs per task (default 10)')
    p.add_argument('--work-dir', default=None,
                   help='where the study directories go (default: a new temporary one)')
    p.set_defaults(func=cmd_bench)
