"""``rths bench faults``: the composed realtime loop under load and faults, measured.

Each case is one composed run of ``rths bench loop`` (:func:`rths_bench.bench_loop.run_once`:
the same config, clock and analysis) at ``--rate`` Hz for ``--duration`` s, with:

* ``baseline``: nothing else started;
* ``cpu_hog``: one busy process per core at normal priority (``nproc`` processes);
  the threads of the composed process and the recorder are listed with their
  scheduling policy, priority, nice value, CPUs and CPU time (``threads``);
* ``memory_hog``: one process holding ``--memory-fraction`` of the RAM available
  at its start (pages written and re-touched), never leaving less than
  MEMORY_RESERVE_MB available (it stops allocating first);
* ``io_hog``: one process writing and fsyncing 8 MiB blocks beside the bag, at
  most IO_HOG_MB on disk (it rewrites the file), deleted after;
* ``stall_NODE_MS``: every STALL_EVERY_S s (half the run if shorter) the node
  (numerical, compensator, bridge) sleeps MS ms before it publishes a step (the system tests' fault
  injection, ``rths_system_tests.faults``); in the composed layout the whole
  executor and the bridge's clock stall with it;
* ``kill_container`` / ``kill_recorder``: SIGKILL of the composed process or of
  the recorder half way through the run; the bag is read as the launcher left
  it (reindexed) and ``loss_before_kill_ms`` is the time from the last bridge
  tick in the bag to the last tick the loop produced before the kill
  (:func:`loss_before_kill`).

Per case: ``deadline_misses``, ``late_or_missed_pct``, ``stalled_ticks``,
``command_peak_m`` / ``velocity_peak_m_s`` / ``acceleration_peak_m_s2`` of what
the bridge wrote (``Measurement.applied``) against the bridge's ``stroke_m``,
``velocity_m_s``, ``acceleration_m_s2`` (``within_limits``), ``final_safety_state``
against ``expected_safety_state`` (:data:`EXPECTED_STATE`, documented in
docs/reliability.md; ``state_as_documented``), and ``samples_produced`` (bridge
ticks of the run) against ``samples_in_bag`` (its measurements in the bag,
``samples_lost``; ``bag_prefix_complete``: no sample is missing before the last
one in the bag).

What skips the ticks, measured in the same run (every case but the kills): a
probe process sleeps to the loop's deadlines at SCHED_FIFO 99 and does nothing
else (:class:`FloorProbe`; the platform floor of ``rths bench loop`` taken during
the run, not before it, keeping time as the bridge's clock does).
``floor_late_or_missed_pct`` counts its ticks as the loop's are counted over the
loop's run; ``loop_stalls`` are the loop's clock overruns and
``loop_stalls_shared_with_floor`` / ``stalled_ticks_shared_with_floor`` those that
overlap a stall of the probe (the machine stalled both).  The two may run on
different CPUs: a stall of the loop's CPU alone (a vCPU the hypervisor took) is not
the probe's.  ``--cpus 1`` puts the loop's nodes and the probe on the same CPU (the
recorder and the hogs stay free): a stall of that vCPU then hits both, so what
stalls the loop alone is the loop's own.  ``loop_stalls_on_cpu`` (``rths bench
loop``'s :func:`~rths_bench.bench_loop.stalls_on_cpu`): the stalls the loop's thread
worked through, never leaving the CPU: a probe that only sleeps cannot share those,
whereas the work floor of ``rths bench loop`` shows the vCPU running the same work
3-18x slower in bursts of a few ms.  ``steal_ms`` / ``steal_pct``: the CPU time
the hypervisor took from this VM's CPUs during the run (``/proc/stat``, all CPUs; the
share of their time).  Normal-priority hogs cannot delay SCHED_FIFO threads; a
hypervisor can.
"""

import argparse
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np

# Imports of the commands' code sit in the command functions: rths imports this module
# to build its parser, and every rths command would pay for SciPy, matplotlib and ROS.

#: Stall lengths [ms] injected in each node, and the nodes.
STALLS_MS = (20, 50, 200)
STALL_NODES = ('numerical', 'compensator', 'bridge')
#: Seconds between two injected stalls of a case.
STALL_EVERY_S = 2.0
#: The bridge supervisor's state at the end of a run per stall length (safety.py's stall
#: policy, stall_limit_s 0.5 s): a stall shorter than stall_limit_s resumes (0, SAFETY_OK),
#: a longer one trips the watchdog and stops safely (3, SAFETY_STOPPED).
STALL_LIMIT_S = 0.5
SAFETY_OK, SAFETY_STOPPED = 0, 3
MEMORY_RESERVE_MB = 768
IO_HOG_MB = 512
#: The kill cases: the run is killed once this share of its ticks is in the bag.
KILL_AT = 0.5


def expected_state(stall_ms: float) -> int:
    """Return the documented final safety state of a run with stalls of ``stall_ms``."""
    return SAFETY_OK if stall_ms * 1e-3 <= STALL_LIMIT_S else SAFETY_STOPPED


EXPECTED_STATE = {ms: expected_state(ms) for ms in STALLS_MS}


def register(commands, benches):
    """Add ``rths bench faults``."""
    p = benches.add_parser(
        'faults', help='the composed loop under CPU/memory/I-O hogs, stalls and kills',
        description='Run the composed realtime loop (as rths bench loop) once per case: '
                    'baseline, a CPU hog on every core, a memory hog, an I/O hog on the '
                    "bag's disk, stalls of 20, 50 and 200 ms in each node, SIGKILL of the "
                    'composed process and of the recorder; per case deadline misses, '
                    'late-or-missed, the command peak against the limits, the safety state '
                    'against the documented one and the samples in the bag against those '
                    'the loop produced; write JSON to --out.')
    p.add_argument('--out', default=None, help='JSON file to write')
    p.add_argument('--rate', type=float, default=1024.0, help='loop rate [Hz] (default 1024)')
    p.add_argument('--duration', type=float, default=10.0,
                   help='length of each run [s] (default 10; 15 cases)')
    p.add_argument('--cases', default='all', help='comma-separated case names or prefixes '
                   '(e.g. baseline,cpu_hog,stall_bridge; default all)')
    p.add_argument('--memory-fraction', type=float, default=0.7,
                   help='share of the available RAM the memory hog holds (default 0.7, at most '
                        f'0.9; it always leaves {MEMORY_RESERVE_MB} MB available)')
    p.add_argument('--taps', type=int, default=400, help='FIR taps of the compensator '
                   '(default 400)')
    p.add_argument('--priority', type=int, default=80, help='SCHED_FIFO priority of the '
                   'bridge (the others 1 less; 0 = normal scheduling; default 80)')
    p.add_argument('--cpus', default='', help="CPUs of the loop's three nodes and of the "
                   "probe, e.g. '1' ('' = none, default): on one CPU a stall of that vCPU "
                   'hits both, so a stall of the loop alone is its own')
    p.add_argument('--keep', default=None, help='keep configs, bags and logs here')
    p.set_defaults(func=cmd_bench_faults)


def case_names() -> list:
    """Return every case of the bench, in run order."""
    return (['baseline', 'cpu_hog', 'memory_hog', 'io_hog']
            + [f'stall_{node}_{ms}' for node in STALL_NODES for ms in STALLS_MS]
            + ['kill_container', 'kill_recorder'])


def select(spec: str) -> list:
    """Return the cases ``spec`` names ('all', or comma-separated names/prefixes)."""
    names = case_names()
    if spec.strip() == 'all':
        return names
    out = []
    for part in (p.strip() for p in spec.split(',') if p.strip()):
        hits = [n for n in names if n == part or n.startswith(part)]
        if not hits:
            raise ValueError(f'--cases {part!r}: no such case; use one of {", ".join(names)}')
        out += [n for n in hits if n not in out]
    return out


def loop_args(args) -> argparse.Namespace:
    """Return the ``rths bench loop`` options of the runs (its defaults, composed)."""
    return argparse.Namespace(layout='composed', taps=args.taps, model='sdof', clock='loop',
                              executor='events', priority=args.priority, cpus=args.cpus,
                              gc='freeze',
                              watchdog_steps=10, margin=0.0, status_every=1, no_bag=False,
                              recorder_nice=10, recorder_cpus='', live=False)


# --------------------------------------------------------------------------- load

HOGS = {
    'cpu': 'while True:\n    pass\n',
    'memory': '''
import sys, time
target, reserve = int(sys.argv[1]), int(sys.argv[2])
def available():
    for line in open('/proc/meminfo'):
        if line.startswith('MemAvailable:'):
            return int(line.split()[1]) * 1024
blocks = []
while sum(len(b) for b in blocks) < target and available() > reserve + (64 << 20):
    b = bytearray(64 << 20)
    b[::4096] = b'\\x01' * len(range(0, len(b), 4096))
    blocks.append(b)
print(sum(len(b) for b in blocks), flush=True)
while True:
    for b in blocks:
        b[::4096] = b'\\x02' * len(range(0, len(b), 4096))
        if available() < reserve:
            blocks.pop()
            break
    time.sleep(0.2)
''',
    'io': '''
import os, sys
path, limit = sys.argv[1], int(sys.argv[2])
block = os.urandom(8 << 20)
with open(path, 'wb') as f:
    while True:
        f.write(block)
        f.flush()
        os.fsync(f.fileno())
        if f.tell() >= limit:
            f.seek(0)
''',
}


def mem_available() -> int:
    """Return MemAvailable [bytes] (0 if unknown)."""
    try:
        for line in Path('/proc/meminfo').read_text().splitlines():
            if line.startswith('MemAvailable:'):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


class Hogs:
    """Start the load of a case; stop (SIGKILL) every process it started on exit."""

    def __init__(self, kind: str, workdir: Path, memory_fraction: float):
        self.kind, self.workdir, self.fraction = kind, workdir, memory_fraction
        self.procs: list = []
        self.info: dict = {}

    def _start(self, code, *argv):
        self.procs.append(subprocess.Popen([sys.executable, '-c', code, *map(str, argv)],
                                           stdout=subprocess.PIPE, text=True))

    def __enter__(self):
        if self.kind == 'cpu':
            for _ in range(os.cpu_count() or 1):
                self._start(HOGS['cpu'])
            self.info = {'processes': len(self.procs), 'nice': 0}
        elif self.kind == 'memory':
            avail = mem_available()
            target = int(avail * self.fraction)
            self._start(HOGS['memory'], target, MEMORY_RESERVE_MB << 20)
            held = self.procs[0].stdout.readline().strip()
            self.info = {'available_mb': avail >> 20, 'held_mb': int(held or 0) >> 20,
                         'available_after_mb': mem_available() >> 20}
        elif self.kind == 'io':
            self.workdir.mkdir(parents=True, exist_ok=True)
            self.path = self.workdir / 'io_hog.bin'
            self._start(HOGS['io'], self.path, IO_HOG_MB << 20)
            self.info = {'file': str(self.path), 'max_mb': IO_HOG_MB, 'block_mb': 8,
                         'fsync': 'every block'}
        return self

    def __exit__(self, *exc):
        for proc in self.procs:
            proc.kill()
            proc.wait()
        if self.kind == 'io':
            self.info['written_mb_at_least'] = (self.path.stat().st_size >> 20
                                                if self.path.exists() else 0)
            self.path.unlink(missing_ok=True)


# --------------------------------------------------------------------------- threads

_POLICIES = {os.SCHED_OTHER: 'SCHED_OTHER', os.SCHED_FIFO: 'SCHED_FIFO',
             os.SCHED_RR: 'SCHED_RR', getattr(os, 'SCHED_BATCH', 3): 'SCHED_BATCH',
             getattr(os, 'SCHED_IDLE', 5): 'SCHED_IDLE'}


def threads_of(pid: int) -> list:
    """Return every thread of ``pid``: name, policy, RT priority, nice, CPUs, CPU seconds."""
    out = []
    tick = os.sysconf('SC_CLK_TCK')
    for tid in sorted(int(t) for t in os.listdir(f'/proc/{pid}/task')):
        try:
            name = Path(f'/proc/{pid}/task/{tid}/comm').read_text().strip()
            fields = Path(f'/proc/{pid}/task/{tid}/stat').read_text().rsplit(')', 1)[1].split()
            out.append({'tid': tid, 'name': name,
                        'policy': _POLICIES.get(os.sched_getscheduler(tid), '?'),
                        'rt_priority': os.sched_getparam(tid).sched_priority,
                        'nice': int(fields[16]),
                        'cpus': sorted(os.sched_getaffinity(tid)),
                        'cpu_s': round((int(fields[11]) + int(fields[12])) / tick, 2)})
        except (OSError, IndexError, ValueError):
            continue          # the thread ended meanwhile
    return out


def run_children(word: str) -> list:
    """Return the pids of this process's children running the executable ``word``."""
    me = os.getpid()
    out = []
    for entry in os.listdir('/proc'):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f'/proc/{entry}/stat').read_text()
            ppid = int(stat.rsplit(')', 1)[1].split()[1])
            argv = Path(f'/proc/{entry}/cmdline').read_bytes().split(b'\0')[:2]
        except (OSError, ValueError, IndexError):
            continue
        if ppid == me and word in (os.path.basename(a.decode(errors='replace')) for a in argv):
            out.append(int(entry))
    return out


class Watcher(threading.Thread):
    """During a run: list the threads (``threads``) or SIGKILL a process (``kill``) mid-run."""

    def __init__(self, bag: Path, steps: int, kill: str = '', list_threads: bool = False):
        super().__init__(daemon=True)
        self.bag, self.steps, self.kill, self.list_threads = bag, steps, kill, list_threads
        self.done = threading.Event()
        self.result: dict = {}

    def run(self):
        """Wait until KILL_AT of the run is in the bag, then list or kill."""
        from rths_common import bagstore, topics

        while not self.done.wait(0.05):
            have = bagstore.committed_counts(self.bag).get(topics.MEASUREMENT, 0) \
                if self.bag.exists() else 0
            if have < KILL_AT * self.steps:
                continue
            if self.list_threads:
                self.result['threads'] = {w: [t for pid in run_children(w)
                                              for t in threads_of(pid)]
                                          for w in ('container', 'recorder')}
            if self.kill:
                pids = run_children(self.kill)
                for pid in pids:
                    os.kill(pid, signal.SIGKILL)
                self.result.update(killed=self.kill, killed_pids=pids,
                                   kill_wall_ns=time.time_ns())
            return

    def stop(self):
        """End the watch (the run is over)."""
        self.done.set()
        self.join(5.0)


# --------------------------------------------------------------------------- the machine's share

def steal_jiffies() -> tuple:
    """Return (steal, all) jiffies of every CPU so far (``/proc/stat``'s ``cpu`` line)."""
    try:
        fields = Path('/proc/stat').read_text().split('\n', 1)[0].split()[1:]
    except OSError:
        return 0, 0
    values = [int(x) for x in fields[:8]]    # user nice system idle iowait irq softirq steal
    return values[7], sum(values)


#: The probe runs at the highest SCHED_FIFO priority: it preempts the loop's threads (for
#: some microseconds a wake-up), so only what the machine does to every thread delays it.
PROBE_PRIORITY = 99
_PROBE = """
import os, signal, sys, threading
import numpy as np
from rths_bench.bench_loop import sleep_to_deadlines
if sys.argv[5]:
    os.sched_setaffinity(0, {int(c) for c in sys.argv[5].split(',')})
stop = threading.Event()
signal.signal(signal.SIGTERM, lambda *_: stop.set())
r = sleep_to_deadlines(float(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]), stop, reanchor=True)
np.savez(sys.argv[4], late_ns=r['late_ns'], wall_ns=r['wall_ns'], scheduling=r['scheduling'])
"""


class FloorProbe:
    """During a run: an empty process sleeping to the loop's deadlines (module doc).

    A process of its own: a thread of this one would wait for the GIL (up to the
    5 ms switch interval) behind the bench's own Python threads.
    """

    def __init__(self, rate_hz: float, duration_s: float, out: Path, cpus: str = ''):
        self.out = Path(out)
        n = int((duration_s + 120.0) * rate_hz)     # start-up and the tail included
        self.proc = subprocess.Popen([sys.executable, '-c', _PROBE, str(rate_hz), str(n),
                                      str(PROBE_PRIORITY), str(self.out), cpus])
        self.woke: dict = {}

    def stop(self):
        """End the probe and read what it measured."""
        self.proc.terminate()
        try:
            self.proc.wait(10.0)
            with np.load(self.out) as r:
                self.woke = {k: r[k] for k in ('late_ns', 'wall_ns')}
                self.woke['scheduling'] = str(r['scheduling'])
        except (subprocess.TimeoutExpired, OSError, KeyError, ValueError):
            self.proc.kill()
            self.woke = {}


def stall_intervals(wall_ns, late_ns, period_ns: int) -> np.ndarray:
    """Return [start, end] wall times [ns] of the wake-ups more than a period late."""
    wall, late = np.asarray(wall_ns, np.int64), np.asarray(late_ns, np.int64)
    hit = late > period_ns
    return np.stack([wall[hit] - late[hit], wall[hit]], axis=1)


def shared_stalls(loop: np.ndarray, probe: np.ndarray, period_ns: int) -> np.ndarray:
    """Return a mask of the ``loop`` stall intervals that overlap a ``probe`` one (± a period)."""
    if not loop.size or not probe.size:
        return np.zeros(len(loop), bool)
    order = np.argsort(probe[:, 0])
    starts, ends = probe[order, 0], np.maximum.accumulate(probe[order, 1])
    # the last probe stall starting before this loop stall ends (+ a period) ...
    i = np.searchsorted(starts, loop[:, 1] + period_ns, side='right') - 1
    # ... overlaps it when the probe stalls up to it end after this one starts (- a period)
    return (i >= 0) & (ends[np.maximum(i, 0)] >= loop[:, 0] - period_ns)


def machine_share(probe: FloorProbe, bridge_timing: Path, steal: tuple, wall_s: float,
                  rate_hz: float) -> dict:
    """Return the probe's and the hypervisor's figures of one run (module doc).

    The probe's ticks count from the loop's first tick to its last (its start-up
    and tail are not the loop's time), all of them if the loop left no timing.
    """
    from rths_bench.bench_loop import _stalled

    period_ns = int(round(1e9 / rate_hz))
    out: dict = {}
    woke = probe.woke
    try:
        with np.load(bridge_timing) as t:
            wall, late = t['tick_wall_ns'], t['tick_late_ns']
    except (OSError, KeyError, ValueError):
        wall = late = None
    if woke.get('late_ns') is not None and woke['late_ns'].size:
        inside = np.ones(woke['wall_ns'].size, bool)
        if wall is not None and wall.size:
            inside = (woke['wall_ns'] >= wall[0]) & (woke['wall_ns'] <= wall[-1])
        p_late = woke['late_ns'][inside]
        if p_late.size:     # counted as the loop's ticks are (bench_loop's late_or_missed_pct)
            out.update(floor_scheduling=woke['scheduling'],
                       floor_late_or_missed_pct=_stalled(p_late, period_ns, 0)[
                           'late_or_missed_pct'],
                       floor_late_us_p99=round(float(np.percentile(p_late, 99)) * 1e-3, 1),
                       floor_late_us_max=round(float(p_late.max()) * 1e-3, 1))
        if wall is not None:
            loop = stall_intervals(wall, late, period_ns)
            hit = shared_stalls(loop, stall_intervals(woke['wall_ns'][inside], p_late,
                                                      period_ns), period_ns)
            skipped = np.asarray(late, np.int64)[np.asarray(late) > period_ns] // period_ns
            out.update(loop_stalls=int(len(loop)), loop_stalls_shared_with_floor=int(hit.sum()),
                       stalled_ticks_shared_with_floor=int(skipped[hit].sum()))
    (s0, a0), (s1, a1) = steal, steal_jiffies()
    if a1 > a0:
        out.update(steal_ms=round(1000.0 * (s1 - s0) / os.sysconf('SC_CLK_TCK'), 1),
                   steal_pct=round(100.0 * (s1 - s0) / (a1 - a0), 3),
                   wall_s=round(wall_s, 2))
    return out


# --------------------------------------------------------------------------- a case

def command_peaks(bag, fs_hz: float) -> dict:
    """Return the peaks of what the bridge wrote (``Measurement.applied``, channel 0)."""
    from rths_common import bagio, topics

    data = bagio.step_arrays(bag, topics.MEASUREMENT, ('applied',))
    if data['step'].size == 0:
        return {'command_peak_m': None}
    order = np.argsort(data['step'], kind='stable')
    u = data['applied'][order, 0]
    u = u[np.isfinite(u)]
    v = np.diff(u) * fs_hz
    a = np.diff(v) * fs_hz
    return {'command_peak_m': float(np.max(np.abs(u))) if u.size else None,
            'command_infinite': int(np.sum(np.isinf(data['applied'][:, 0]))),
            'velocity_peak_m_s': float(np.max(np.abs(v))) if v.size else 0.0,
            'acceleration_peak_m_s2': float(np.max(np.abs(a))) if a.size else 0.0}


def bag_side(bag, fs_hz: float, limits: dict) -> dict:
    """Return the bag's side of a case: peaks against limits, final state, verification."""
    from rths_common import bagio, topics
    from rths_review.evidence import verify

    out = command_peaks(bag, fs_hz)
    if out['command_peak_m'] is not None:
        out['within_limits'] = bool(
            out['command_peak_m'] <= limits['stroke_m'] + 1e-9
            and out['velocity_peak_m_s'] <= limits['velocity_m_s'] * (1 + 1e-6) + 1e-9
            and out['acceleration_peak_m_s2'] <= limits['acceleration_m_s2'] * (1 + 1e-6)
            + 1e-6)
    out['limits'] = limits
    states, stamps = [], []
    for _, _, msg in bagio.read_messages(bag, [topics.STATUS]):
        if msg.node == 'bridge':
            states.append(int(msg.safety_state))
            stamps.append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
    out['final_safety_state'] = states[-1] if states else None
    out['worst_safety_state'] = max((s for s in states if s != 4), default=None)
    out['last_bridge_stamp_ns'] = max(stamps) if stamps else None
    steps = set(bagio.step_arrays(bag, topics.MEASUREMENT, ())['step'].tolist())
    out['samples_in_bag'] = len(steps)
    # every sample up to the last one in the bag is there (a killed recorder loses a tail only)
    out['bag_prefix_complete'] = not steps or len(steps) == max(steps) + 1
    report = verify(bag)
    out['verify_problems'] = report['problems']
    return out


def loss_before_kill(result: dict, bridge_timing: Path) -> dict:
    """Return ``loss_before_kill_ms``: what of the loop's output before the kill the bag lacks.

    The span from the last bridge tick in the bag to the last tick the loop
    produced before the kill (``last_produced_before_kill_ns``).  A killed
    recorder leaves the loop running: its ticks come from the bridge's timing
    file (wall clock, as the stamps), so a kill that lands after the loop's end
    loses nothing.  A killed container writes no timing file: its last tick is
    taken as the kill itself (an upper bound).
    """
    kill_ns, in_bag_ns = result['kill_wall_ns'], result['last_bridge_stamp_ns']
    last_ns = kill_ns
    if bridge_timing.exists():
        ticks = np.load(bridge_timing)['tick_wall_ns']
        before = ticks[ticks <= kill_ns]
        if before.size:
            last_ns = int(before.max())
    return {'last_produced_before_kill_ns': last_ns,
            'loss_before_kill_ms': round(max(last_ns - in_bag_ns, 0) * 1e-6, 1)}


def run_case(name: str, args, workdir: Path, log) -> dict:
    """Run one case; return its result (module doc)."""
    from rths_actuator_bridge.safety import SAFETY_PARAMS
    from rths_bench.bench_loop import run_once

    la = loop_args(args)
    limits = {k: SAFETY_PARAMS[k][0] for k in ('stroke_m', 'velocity_m_s', 'acceleration_m_s2')}
    steps = int(args.rate * args.duration)
    bag = workdir / 'bag'
    kind = name.split('_')[0]
    env_before = dict(os.environ)
    stall_ms = 0
    result: dict = {'case': name}
    if kind == 'stall':
        _, node, ms = name.split('_')
        stall_ms = int(ms)
        try:
            # lazy: the system tests' fault injection (installed by make setup), only here
            from rths_system_tests.faults import overlay_env
        except ImportError:
            raise OSError('the stall cases need the system tests package rths_system_tests '
                          "(run 'make setup')") from None
        every = max(min(int(STALL_EVERY_S * args.rate), steps // 2), 1)
        os.environ.update(overlay_env(dict(os.environ), {node: {'delay_every': every,
                                                                'delay_ms': float(ms)}}))
        result.update(stall_node=node, stall_ms=stall_ms, stall_every_steps=every,
                      stalls=int((steps - 1) // every))
    watcher = Watcher(bag, steps, kill={'kill': name.split('_')[-1]}.get(kind, ''),
                      list_threads=kind == 'cpu')
    hog = Hogs(kind, workdir, args.memory_fraction) if kind in ('cpu', 'memory', 'io') else None
    probe = None
    try:
        watcher.start()
        if hog is not None:
            hog.__enter__()
        if kind != 'kill':
            workdir.mkdir(parents=True, exist_ok=True)
            probe = FloorProbe(args.rate, args.duration, workdir / 'floor_probe.npz',
                               args.cpus)
        steal, t_start = steal_jiffies(), time.monotonic()
        try:
            loop = run_once(args.rate, args.duration, la, workdir, log, label=name)
        except OSError as err:            # a killed container wrote no timing files
            loop = {'run_completed': False, 'loop_error': str(err).split(';')[0]}
        finally:
            if probe is not None:
                probe.stop()
                result.update(machine_share(probe, workdir / 'bridge_timing.npz', steal,
                                            time.monotonic() - t_start, args.rate))
            if hog is not None:
                hog.__exit__(None, None, None)
                result['load'] = hog.info
    finally:
        watcher.stop()
        os.environ.clear()
        os.environ.update(env_before)
    result.update({k: loop.get(k) for k in (
        'steps', 'deadline_misses', 'deadline_miss_pct', 'late_or_missed_pct', 'stalled_ticks',
        'clock_overruns', 'run_completed', 'loop_error', 'latency_us_p99', 'cpu_pct',
        'loadavg_before', 'loadavg_after', 'loop_stalls_on_cpu', 'loop_stall_ms_on_cpu',
        'loop_stall_ms_off_cpu') if k in loop})
    result.update(watcher.result)
    if bag.exists():
        result.update(bag_side(bag, args.rate, limits))
    produced = loop.get('steps')
    if produced is not None and 'samples_in_bag' in result:
        result['samples_produced'] = produced
        result['samples_lost'] = max(produced - result['samples_in_bag'], 0)
    if 'kill_wall_ns' in result and result.get('last_bridge_stamp_ns'):
        result.update(loss_before_kill(result, workdir / 'bridge_timing.npz'))
    if kind == 'stall':
        result['expected_safety_state'] = expected_state(stall_ms)
        result['state_as_documented'] = result.get('final_safety_state') == \
            result['expected_safety_state']
    return result


def print_case(r: dict) -> None:
    """Print one case on one line."""
    extra = ''
    if 'expected_safety_state' in r:
        extra = (f", expected {r['expected_safety_state']} "
                 f"({'as documented' if r['state_as_documented'] else 'NOT AS DOCUMENTED'})")
    if 'loss_before_kill_ms' in r:
        extra += f", bag ends {r['loss_before_kill_ms']} ms before the kill"
    print(f"{r['case']}: misses {r.get('deadline_misses')}, late-or-missed "
          f"{r.get('late_or_missed_pct')} %, stalled ticks {r.get('stalled_ticks')}, command "
          f"peak {r.get('command_peak_m')} m (within limits {r.get('within_limits')}), final "
          f"safety state {r.get('final_safety_state')}{extra}, samples "
          f"{r.get('samples_in_bag')}/{r.get('samples_produced')} in the bag", flush=True)
    if 'floor_late_or_missed_pct' in r:
        print(f"  same run: an empty SCHED_FIFO 99 process "
              f"{r['floor_late_or_missed_pct']} % late or missed; "
              f"{r.get('stalled_ticks_shared_with_floor')} of the loop's "
              f"{r.get('stalled_ticks')} stalled ticks in stalls it shared; hypervisor steal "
              f"{r.get('steal_ms')} ms ({r.get('steal_pct')} % of the CPUs' time)", flush=True)


def cmd_bench_faults(args) -> int:
    """Run ``rths bench faults``: every selected case, then write JSON."""
    from rths_bench.bench_loop import domain_id, machine_info
    from rths_common.node_support import parse_cpus

    if not args.rate > 0 or not args.duration > 0:
        raise ValueError('--rate and --duration must be > 0')
    if not 0 < args.memory_fraction <= 0.9:
        raise ValueError(f'--memory-fraction {args.memory_fraction}: use (0, 0.9]')
    cpus = parse_cpus(args.cpus)
    if not cpus <= os.sched_getaffinity(0):
        raise ValueError(f'--cpus {args.cpus!r}: this machine has CPUs '
                         f'{sorted(os.sched_getaffinity(0))}')
    args.cpus = ','.join(str(c) for c in sorted(cpus))     # the probe's form: '1', '0,1'
    cases = select(args.cases)
    keep = Path(args.keep) if args.keep else None
    date = time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime())
    report: dict = {'machine': machine_info(), 'date': date, 'rate_hz': args.rate,
                    'duration_s': args.duration, 'cpus': args.cpus,
                    'expected_safety_state_by_stall_ms':
                    {str(k): v for k, v in EXPECTED_STATE.items()},
                    'stall_limit_s': STALL_LIMIT_S, 'cases': {}}
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix='rths-bench-faults-') as tmp:
        base = keep or Path(tmp)
        base.mkdir(parents=True, exist_ok=True)
        os.environ['ROS_DOMAIN_ID'] = str(domain_id(-1))
        with open(base / 'launch.log', 'w') as log:
            for i, name in enumerate(cases):
                print(f'[{i + 1}/{len(cases)}] {name} ...', flush=True)
                r = run_case(name, args, base / name, log)
                print_case(r)
                report['cases'][name] = r
    report['wall_s'] = round(time.monotonic() - t0, 1)
    report['machine']['loadavg_end'] = [round(x, 2) for x in os.getloadavg()]
    stalls = [r for r in report['cases'].values() if 'state_as_documented' in r]
    report['summary'] = {
        'all_within_limits': all(r.get('within_limits', True) for r in report['cases'].values()),
        'stall_states_as_documented': all(r['state_as_documented'] for r in stalls),
        'samples_lost_under_load': {n: r.get('samples_lost') for n, r in report['cases'].items()
                                    if n.endswith('_hog')},
        'loss_before_kill_ms': {n: r.get('loss_before_kill_ms')
                                for n, r in report['cases'].items() if n.startswith('kill_')},
    }
    print(json.dumps(report['summary']), flush=True)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(report, indent=2))
        print(f'wrote {args.out}')
    return 0
