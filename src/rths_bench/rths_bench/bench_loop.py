"""``rths bench loop``: the realtime loop of the three nodes, measured, in either layout.

Runs the numerical node, the compensator and the actuator bridge (simulated
plant) through the launcher, composed in one process (``--layout composed``,
the default: :mod:`rths_bringup.container`) or as separate processes
(``--layout processes``; the JSON's ``layout`` says which), in realtime mode at
``--rate`` Hz for ``--duration`` s, from a config generated into a temporary
directory, recording a bag; then reads the nodes' timing files and the bag
and writes JSON:

* ``rate_hz``, ``steps`` (bridge ticks of the run), ``deadline_miss_pct``
  (ticks whose command had not arrived, per the bridge);
* ``latency_us_p50/p99/max``: numerical-command-to-bridge latency, from the
  numerical node's publish stamp of step k (InterfaceDisplacement) to the
  bridge's receipt of command k (late commands included, lost ones counted
  apart); ``use_latency_us_*`` to the tick that used it; ``loop_us_*`` the
  round trip from tick k's measurement to the receipt of command k+1 (must be
  below one period), in three parts: ``measurement_us_*`` from tick k to the
  numerical node's receipt of measurement k, ``numerical_us_*`` from there to
  its publish of step k+1, and ``latency_us_*`` of step k+1 (the compensator
  and its two hops); ``tick_late_us_*`` the clock's jitter;
* ``cpu_pct``: CPU time of the three node processes (composed: the container)
  over the run's wall time (100 = one core; the machine has ``nproc`` cores),
  per process in ``cpu_pct_per_node`` (recorder included);
* ``clock_overruns`` / ``clock_overrun_pct``: ticks that came more than a
  period late (the bridge's process itself stalled; the clock re-anchors),
  ``stalled_ticks`` the ticks those stalls skipped; ``late_or_missed_pct``
  (deadline misses + stalled ticks over all ticks due) is what ``--find-max``
  and ``meets_targets`` hold to 0.1 %: in the composed layout a stall delays
  the whole chain with the clock, so it shows as stalled ticks, not as misses;
* ``recorder_loss``: per loop topic, steps of the run missing from the bag
  (processes: the recorder subscribes best-effort in realtime; composed: it
  reads the container's recording pipe and must lose nothing), and the consistency of
  the bridge's status accounting with the bag;
* machine info: ``nproc``, ``cpu_model``, load average before and after;
* ``platform_floor`` (``--floor S``, default 10 s, before the runs): one
  SCHED_FIFO thread that only sleeps to absolute ``1/rate`` deadlines, as
  cyclictest does, and its wake-up lateness; ``late_gt_period_pct`` is the
  miss rate of an empty loop, the floor no node code can go below (on a
  loaded VM, vCPU stalls of several ms show up here);
  ``platform_floor.work`` (:func:`work_floor`, as long again, after it): the
  same fixed pure-Python work every 1/1024 s at SCHED_FIFO and how often it
  took more than 3x its median (``stretched_pct``), with the share of those
  during which the thread never left the CPU (``stretched_on_cpu_pct``): a vCPU
  that runs slower for a few ms, which the wake-up floor cannot see;
* ``loop_stalls`` (ticks more than a period late) and ``loop_stalls_on_cpu``, those
  the ticking thread worked through (its CPU time grew by >= 90 % of the
  stall: its own work took that long) with ``loop_stall_ms_on_cpu`` /
  ``loop_stall_ms_off_cpu`` (:func:`stalls_on_cpu`); ``tick_cpu_us_*``: the
  ticking thread's CPU time from one tick to the next (composed: every node's
  step, the executor's passes and the waits' own cost; the loop's work per
  tick, which stalls of the host stretch but do not add to);
* ``ros_domain_id``: the runs use a private DDS domain (``--domain-id``;
  default: ``ROS_DOMAIN_ID`` if set, else one derived from the process id),
  so another graph running on the machine cannot feed the bench's topics.

``--find-max`` steps the rate up (1024, 1536, 2048, ...; until a run aborts
or misses more than 10 %) and reports the highest rate with at most 0.1 %
of its ticks missed or skipped by stalls (``late_or_missed_pct``); every
rate's result is in ``runs``.
"""

from contextlib import contextmanager
import gc
import json
import os
from pathlib import Path
import platform
import tempfile
import time

import numpy as np

from rths_actuator_bridge.bridge import DEFAULT_BACKEND
from rths_common.stepping import TickClock
from rths_compensator.schemes import DEFAULT_SCHEME
from rths_numerical.specimens import DEFAULT_SPECIMEN

# Imports of the commands' code sit in the command functions: rths imports this module
# to build its parser, and every rths command would pay for SciPy, matplotlib and ROS.

MISS_TARGET_PCT = 0.1
GIVE_UP_PCT = 10.0  # --find-max stops stepping the rate up past this miss rate
FIND_MAX_RATES = (1024, 1536, 2048, 2560, 3072, 4096)
#: A stall (or a work chunk) during which the thread's CPU time grew by at least this share
#: of its wall time never left the CPU.
ON_CPU = 0.9
#: The work floor's chunk [loop iterations of a float sum]: about 130-190 us on the 2-core
#: AMD EPYC VM of 2026-11-28 (the two vCPUs differed by 1.5x) ...
WORK_CHUNK = 3000
#: ... and a chunk that took more than this many times the median is stretched.
STRETCH = 3.0


def register(commands, benches):
    """Add ``rths bench loop``."""
    p = benches.add_parser(
        'loop', help='realtime loop of the three nodes: deadline misses, latency, CPU',
        description='Run the three nodes (simulated plant) in realtime mode through the '
                    'launcher, composed in one process (default) or as three processes, and '
                    'measure deadline misses, numerical-to-bridge latency, clock jitter, CPU '
                    'and recorder loss; write JSON to --out.')
    p.add_argument('--layout', default='composed', choices=('composed', 'processes'),
                   help='composed: the three nodes in one process on one executor (default); '
                        'processes: one process per node')
    p.add_argument('--rate', type=float, default=1024.0, help='loop rate [Hz] (default 1024)')
    p.add_argument('--duration', type=float, default=10.0, help='run length [s] (default 10)')
    p.add_argument('--out', default=None, help='JSON file to write')
    p.add_argument('--taps', type=int, default=400, help='FIR taps of the compensator '
                   '(default 400, as designed in section 6.1)')
    p.add_argument('--model', default='sdof', help='numerical model: sdof (default) or '
                   'building2story (uncompensated it can go unstable: the bridge aborts)')
    p.add_argument('--clock', default='loop', choices=('loop', 'thread', 'timer'),
                   help="the bridge's clock (default loop)")
    p.add_argument('--margin', type=float, default=0.0, help="the 'loop' clock's polling "
                   'time before each tick [us] (default 0: wait in spin_once only)')
    p.add_argument('--executor', default='events', choices=('events', 'single'),
                   help='executor of the three nodes (default events)')
    p.add_argument('--priority', type=int, default=80, help='SCHED_FIFO priority of the '
                   'bridge; the compensator and numerical node get 1 less (0 = normal '
                   'scheduling; default 80)')
    p.add_argument('--cpus', default='', help="CPU affinity of the loop nodes: '' (none, "
                   "default), one list for all ('1') or three 'bridge/compensator/numerical' "
                   "('1/0/0')")
    p.add_argument('--gc', default='freeze', choices=('default', 'freeze', 'disable'),
                   help='garbage-collector handling in the loop nodes (default freeze)')
    p.add_argument('--watchdog-steps', type=int, default=10, help="the bridge supervisor's "
                   'watchdog: consecutive misses that abort the run (default 10, as the bridge)')
    p.add_argument('--status-every', type=int, default=1, help='numerical and compensator '
                   'publish the status of every N-th step only (default 1: every step; the '
                   'bridge always reports every step)')
    p.add_argument('--rate-divisor', type=int, default=1, help='integrate the numerical '
                   'substructure at RATE / N and interpolate its output to every loop step '
                   "(the numerical node's rate_divisor, a multi-rate layout; default 1)")
    p.add_argument('--no-direct-delivery', action='store_true',
                   help="composed: the loop messages between the three nodes over DDS, as "
                   "before direct delivery (the bridge's direct_delivery: false; to compare)")
    p.add_argument('--no-bag', action='store_true', help='do not record (no recorder process)')
    p.add_argument('--recorder-nice', type=int, default=10, help='nice value of the recorder '
                   "process's threads (normal scheduling; default 10)")
    p.add_argument('--recorder-cpus', default='', help="CPU affinity of the recorder ('' = "
                   "none, default; e.g. '0' with --cpus 1 keeps it off the loop's core)")
    p.add_argument('--find-max', action='store_true', help='step the rate up from 1024 Hz '
                   'and report the highest with <= 0.1 %% of ticks missed or skipped by stalls')
    p.add_argument('--floor', type=float, default=10.0, help='seconds of the platform '
                   'wake-up floor measurement before the runs (0 = skip; default 10)')
    p.add_argument('--domain-id', type=int, default=-1, help='ROS_DOMAIN_ID of the runs '
                   '(default -1: $ROS_DOMAIN_ID if set, else a private one from the pid)')
    p.add_argument('--keep', default=None, help='keep config, bag and timing files here')
    from rths_live import live
    live.add_arguments(p)   # --live: the misses with the live view on (issue 17)
    p.set_defaults(func=cmd_bench_loop)


def write_config(directory, rate_hz=1024.0, duration_s=10.0, taps=400, model='sdof',
                 clock='loop', executor='events', priority=0, cpus='', gc_mode='default',
                 record='harmonic', watchdog_steps=10, margin_us=0.0, status_every=1,
                 compensator_filter=None, direct_delivery=True, rate_divisor=1) -> Path:
    """Write bridge/compensator/numerical.yaml of a realtime run (simulated plant).

    The compensator is a ``taps``-tap FIR with the cost of a designed one and
    the effect of a pure gain of 1 (first tap 1, the others 0), so every rate
    runs the same stable loop; ``compensator_filter`` = ``(taps, denominator)``
    runs that filter instead (e.g. a design at ``rate_hz``; ``taps`` is then
    ignored).  ``cpus`` is one affinity list for all nodes or three separated
    by '/' (bridge/compensator/numerical).  (Faults are injected by the system
    tests' wrapper, ``rths_system_tests.faults``, not by parameters.)  ``rate_divisor``
    > 1: the numerical substructure at ``rate_hz / rate_divisor`` (multi-rate).
    """
    import yaml

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    parts = str(cpus).split('/') if cpus else ['']
    if len(parts) not in (1, 3):
        raise ValueError(f"--cpus {cpus!r}: give one CPU list or three separated by '/'")
    cpu_of = dict(zip(('bridge', 'compensator', 'numerical'), parts * 3 if len(parts) == 1
                      else parts, strict=True))
    prio_of = {'bridge': priority, 'compensator': max(priority - 1, 0) if priority else 0,
               'numerical': max(priority - 1, 0) if priority else 0}

    def tuning(name):
        params = {'mode': 'realtime', 'executor': executor, 'rt_priority': int(prio_of[name]),
                  'cpus': cpu_of[name], 'gc': gc_mode}
        if name != 'bridge':
            params['status_every'] = int(status_every)
        return params

    bridge = dict(tuning('bridge'), clock=clock, spin_margin_us=float(margin_us),
                  backend=DEFAULT_BACKEND, fs_hz=float(rate_hz),
                  actuator_model='3pole', specimen=DEFAULT_SPECIMEN, seed=1,
                  watchdog_steps=int(watchdog_steps), direct_delivery=bool(direct_delivery))
    if compensator_filter is None:
        fir, den = [1.0] + [0.0] * (int(taps) - 1), [1.0]
    else:
        fir, den = ([float(v) for v in np.ravel(c)] for c in compensator_filter)
    compensator = dict(tuning('compensator'), scheme=DEFAULT_SCHEME, fs_hz=float(rate_hz),
                       taps=fir, denominator=den)
    numerical = dict(tuning('numerical'), model=model, integrator='cr', fs_hz=float(rate_hz),
                     duration_s=float(duration_s), record=record, scale=0.05)
    if model == 'sdof':
        numerical.update(sdof_mass_kg=1000.0, sdof_freq_hz=2.81, sdof_zeta=0.042)
    if int(rate_divisor) != 1:
        numerical['rate_divisor'] = int(rate_divisor)
    for name, params in (('bridge', bridge), ('compensator', compensator),
                         ('numerical', numerical)):
        (directory / f'{name}.yaml').write_text(
            yaml.safe_dump({name: {'ros__parameters': params}}, sort_keys=False))
    return directory


def _pct(values, q):
    values = np.asarray(values, dtype=float)
    return round(float(np.percentile(values, q)), 1) if values.size else None


def _stats(prefix, values_us) -> dict:
    values = np.asarray(values_us, dtype=float)
    return {f'{prefix}_p50': _pct(values, 50), f'{prefix}_p99': _pct(values, 99),
            f'{prefix}_max': round(float(values.max()), 1) if values.size else None}


def machine_info() -> dict:
    """nproc, CPU model, kernel and load average."""
    model = platform.processor() or ''
    try:
        for line in Path('/proc/cpuinfo').read_text().splitlines():
            if line.startswith('model name'):
                model = line.split(':', 1)[1].strip()
                break
    except OSError:
        pass
    return {'nproc': os.cpu_count(), 'cpu_model': model, 'kernel': platform.release(),
            'loadavg': [round(x, 2) for x in os.getloadavg()]}


def analyse(bridge_npz, numerical_npz, cpu_samples=(), bag=None, rate_hz=None) -> dict:
    """Return the benchmark's numbers from the nodes' timing files, the CPU samples and the bag."""
    br = np.load(bridge_npz)
    nu = np.load(numerical_npz)
    period_ns = int(br['period_ns'])
    in_run = br['tick_step'] < int(br['n_steps']) if int(br['n_steps']) >= 0 else slice(None)
    ticks = br['tick_step'][in_run]   # ticks after the run (a safe stop's ramp) do not count
    missed = br['missed'].astype(bool)[in_run]
    steps = int(ticks.size)
    misses = int(missed.sum())
    # numerical publish stamp of step k -> bridge receipt of command k (first receipt)
    pub = dict(zip(nu['pub_step'].tolist(), nu['pub_wall_ns'].tolist(), strict=True))
    recv = {}
    for step, t_ns in zip(br['recv_step'].tolist(), br['recv_wall_ns'].tolist(), strict=True):
        recv.setdefault(step, t_ns)
    tick_wall = dict(zip(ticks.tolist(), br['tick_wall_ns'][in_run].tolist(), strict=True))
    latency = [(recv[k] - pub[k]) * 1e-3 for k in pub if k in recv and k > 0]
    lost = sum(1 for k in pub if k not in recv and k < steps)
    ticked = zip(ticks.tolist(), missed.tolist(), strict=True)
    use = [(tick_wall[k] - pub[k]) * 1e-3 for k, m in ticked
           if not m and k in pub and k > 0]
    loop = [(recv[k + 1] - tick_wall[k]) * 1e-3 for k in tick_wall if k + 1 in recv]
    got = {}   # the numerical node's first receipt of measurement k
    for step, t_ns in zip(nu['recv_step'].tolist(), nu['recv_wall_ns'].tolist(), strict=True):
        got.setdefault(step, t_ns)
    measurement = [(got[k] - tick_wall[k]) * 1e-3 for k in tick_wall if k in got]
    numerical = [(pub[k + 1] - got[k]) * 1e-3 for k in got if k + 1 in pub]
    out = {
        'rate_hz': float(rate_hz) if rate_hz else 1e9 / period_ns,
        'steps': steps,
        'deadline_misses': misses,
        'deadline_miss_pct': round(100.0 * misses / steps, 4) if steps else None,
        **_stats('latency_us', latency),
        'commands_lost': lost,
        'commands_late': int(br['late']),
        'clock_overruns': int(br['overruns']),
        'clock_overrun_pct': round(100.0 * int(br['overruns']) / steps, 4) if steps else None,
        **_stalled(br['tick_late_ns'][in_run], period_ns, misses),
        **_stats('use_latency_us', use),
        **_stats('loop_us', loop),
        **_stats('measurement_us', measurement),
        **_stats('numerical_us', numerical),
        'period_us': period_ns * 1e-3,
        **_stats('tick_late_us', br['tick_late_ns'][in_run] * 1e-3),
        'numerical_measurements_missed': int(nu['misses']),
    }
    out.update(_cpu(cpu_samples, tick_wall))
    if 'tick_cpu_ns' in br.files:
        out.update(stalls_on_cpu(br['tick_wall_ns'][in_run], br['tick_late_ns'][in_run],
                                 br['tick_cpu_ns'][in_run], period_ns))
        out.update(_stats('tick_cpu_us', np.diff(br['tick_cpu_ns'][in_run]) * 1e-3))
    if bag is not None:
        out['bag'] = bag_check(bag, steps, missed)
    return out


def _stalled(late_ns, period_ns: int, misses: int) -> dict:
    """Return the ticks the clock's stalls skipped and the late-or-missed share of all ticks due."""
    late_ns = np.asarray(late_ns, dtype=np.int64)
    stalled = int(np.sum(late_ns[late_ns > period_ns] // period_ns))
    due = late_ns.size + stalled
    return {'stalled_ticks': stalled,
            'late_or_missed_pct': round(100.0 * (misses + stalled) / due, 4) if due else None}


def stalls_on_cpu(wall_ns, late_ns, cpu_ns, period_ns: int) -> dict:
    """Count the clock's stalls (ticks more than a period late) the ticking thread worked through.

    A stall's interval runs from the tick before it to it.  Where the thread's CPU
    time grew by at least :data:`ON_CPU` of that interval it never left the CPU:
    its own work took that long (the node code, or a vCPU that ran it slower:
    :func:`work_floor`).  The others waited: preempted, blocked, or woken late.
    """
    wall, late, cpu = (np.asarray(a, np.int64) for a in (wall_ns, late_ns, cpu_ns))
    hit = np.flatnonzero(late[1:] > period_ns) + 1
    span = wall[hit] - wall[hit - 1]
    on = (cpu[hit] - cpu[hit - 1]) >= ON_CPU * span
    return {'loop_stalls': int(hit.size), 'loop_stalls_on_cpu': int(on.sum()),
            'loop_stall_ms_on_cpu': round(float(span[on].sum()) * 1e-6, 1),
            'loop_stall_ms_off_cpu': round(float(span[~on].sum()) * 1e-6, 1)}


def _within_target(r: dict) -> bool:
    """Return True if a run completed with <= MISS_TARGET_PCT % of its ticks missed or skipped."""
    pct = r.get('late_or_missed_pct', r.get('deadline_miss_pct'))
    return bool(r['run_completed'] and pct is not None and pct <= MISS_TARGET_PCT)


def _cpu(samples, tick_wall) -> dict:
    """CPU % of each process between the first and last CPU sample inside the run."""
    if not tick_wall:
        return {}
    t_first, t_last = min(tick_wall.values()), max(tick_wall.values())
    inside = [(t, cpu) for t, cpu in samples if t_first <= t <= t_last]
    if len(inside) < 2:
        return {'cpu_pct': None}
    (ta, a), (tb, b) = inside[0], inside[-1]
    wall = (tb - ta) * 1e-9
    per = {name: round(100.0 * (b[name] - a[name]) / wall, 1) for name in b
           if a.get(name) is not None and b[name] is not None}
    loop_nodes = [per[n] for n in ('bridge', 'compensator', 'numerical', 'container')
                  if n in per]
    return {'cpu_pct': round(sum(loop_nodes), 1), 'cpu_pct_per_node': per,
            'cpu_window_s': round(wall, 2)}


def bag_check(bag, steps, missed) -> dict:
    """Return the recorder loss per loop topic and the bridge status accounting against the bag."""
    from rths_common import bagio, topics

    seen = {topics.INTERFACE_DISPLACEMENT: set(), topics.COMMAND: set(),
            topics.MEASUREMENT: set()}
    bridge_status = {}
    for topic, _, msg in bagio.read_messages(bag, list(seen) + [topics.STATUS]):
        if topic == topics.STATUS:
            if msg.node == 'bridge':
                bridge_status[msg.step] = (bool(msg.deadline_missed), int(msg.deadline_misses))
            continue
        seen[topic].add(int(msg.step))
    run = set(range(steps))
    loss = {topic: len(run - got) for topic, got in seen.items()}
    # the compensator publishes every step the numerical node publishes; missed commands are
    # not in the bag either: the recorder loss of /rths/command counts only steps that were sent
    flags = [bridge_status[k][0] for k in sorted(bridge_status) if k < steps]
    final = max((v[1] for v in bridge_status.values()), default=0)
    return {'recorder_loss': loss,
            'recorder_loss_pct': {t: round(100.0 * n / steps, 3) if steps else None
                                  for t, n in loss.items()},
            'bridge_status_steps': len(flags),
            'bridge_status_missed_flags': int(sum(flags)),
            'bridge_status_final_misses': final,
            'status_matches_bridge': bool(sum(flags) == final == int(np.sum(missed)))}


@contextmanager
def fifo_thread(priority: int):
    """Run the calling thread SCHED_FIFO ``priority`` with the collector off; restore both.

    Yields how it is scheduled (SCHED_OTHER where SCHED_FIFO was refused).
    """
    policy, param = os.sched_getscheduler(0), os.sched_getparam(0)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(int(priority)))
        sched = f'SCHED_FIFO {int(priority)}'
    except OSError as err:
        sched = f'SCHED_OTHER (SCHED_FIFO refused: {err})'
    gc_was = gc.isenabled()
    gc.disable()
    try:
        yield sched
    finally:
        if gc_was:
            gc.enable()
        try:
            os.sched_setscheduler(0, policy, param)
        except OSError:
            pass


def sleep_to_deadlines(rate_hz: float, n: int, priority: int = 80, stop=None,
                       reanchor: bool = False) -> dict:
    """Sleep to the deadlines ``t0 + k / rate`` (k < n, or until ``stop`` is set).

    The calling thread runs SCHED_FIFO ``priority`` meanwhile (restored after) and
    does nothing else.  ``reanchor``: keep time as the bridge's clock does
    (:class:`rths_common.stepping.TickClock`: a wake-up more than a period late
    skips the ticks it missed); else the deadlines are fixed (cyclictest).  Returns
    ``late_ns`` (how late each wake-up was), ``wall_ns`` (wall-clock time of each
    wake-up, :func:`time.time_ns`, as the nodes stamp their ticks) and ``scheduling``.
    """
    clock = TickClock(rate_hz)
    late = np.zeros(n, dtype=np.int64)
    wall = np.zeros(n, dtype=np.int64)
    done = 0
    with fifo_thread(priority) as sched:
        clock.start(time.monotonic_ns() + clock.period_ns)
        for k in range(n):
            if stop is not None and stop.is_set():
                break
            wait = clock.due_ns() - time.monotonic_ns()
            if wait > 0:
                time.sleep(wait * 1e-9)
            now = time.monotonic_ns()
            if reanchor:
                _, late[k], _ = clock.take(now)
            else:
                late[k] = now - clock.due_ns()
                clock.k += 1
            wall[k] = time.time_ns()
            done = k + 1
    return {'late_ns': late[:done], 'wall_ns': wall[:done], 'scheduling': sched}


def platform_floor(rate_hz: float, duration_s: float, priority: int = 80) -> dict:
    """Wake-up lateness of an empty SCHED_FIFO loop at ``rate_hz`` (what cyclictest measures).

    This thread sleeps to absolute deadlines ``t0 + k / rate`` and records how
    late it woke; nothing else runs in it (:func:`sleep_to_deadlines`).
    """
    period_ns = int(round(1e9 / rate_hz))
    woke = sleep_to_deadlines(rate_hz, max(int(duration_s * rate_hz), 1), priority)
    late = woke['late_ns']
    late_us = late * 1e-3
    return {'rate_hz': float(rate_hz), 'samples': int(late.size),
            'scheduling': woke['scheduling'],
            **_stats('late_us', late_us),
            'late_us_p999': round(float(np.percentile(late_us, 99.9)), 1),
            'late_gt_period_pct': round(100.0 * float(np.mean(late > period_ns)), 4),
            'loadavg': [round(x, 2) for x in os.getloadavg()]}


def _work_chunk(n: int = WORK_CHUNK) -> float:
    total = 0.0
    for i in range(n):
        total += i * 0.5
    return total


def work_floor(duration_s: float, priority: int = 80, rate_hz: float = 1024.0) -> dict:
    """Time the same pure-Python work (:data:`WORK_CHUNK`) every period at SCHED_FIFO.

    The wake-up floor does no work, so it cannot see a vCPU that keeps running
    but runs slower.  Here each chunk's wall time is measured with the thread's
    CPU time: ``stretched_pct`` is the share of chunks that took more than
    :data:`STRETCH` times the median, ``stretched_on_cpu_pct`` the share of those
    during which the thread never left the CPU (nothing preempted it: the same
    instructions simply took longer).  On the 2-core AMD EPYC VM of 2026-11-28,
    with nothing else running, 65 of 20 000 chunks of 132 us took 3-18x as long,
    61 of them on the CPU, in bursts of a few ms, on one vCPU at a time.
    """
    n = max(int(duration_s * rate_hz), 1)
    period_ns = int(round(1e9 / rate_hz))
    took = np.zeros(n, np.int64)
    cpu = np.zeros(n, np.int64)
    with fifo_thread(priority) as sched:
        due = time.monotonic_ns()
        for k in range(n):
            due += period_ns
            t0, c0 = time.perf_counter_ns(), time.thread_time_ns()
            _work_chunk()
            took[k] = time.perf_counter_ns() - t0
            cpu[k] = time.thread_time_ns() - c0
            wait = due - time.monotonic_ns()
            if wait > 0:
                time.sleep(wait * 1e-9)
            else:
                due = time.monotonic_ns()
    med = float(np.median(took))
    slow = took > STRETCH * med
    on = slow & (cpu >= ON_CPU * took)
    return {'rate_hz': float(rate_hz), 'chunks': n, 'scheduling': sched,
            'chunk_us_p50': round(med * 1e-3, 1),
            'chunk_us_p99': round(float(np.percentile(took, 99)) * 1e-3, 1),
            'chunk_us_max': round(float(took.max()) * 1e-3, 1),
            'stretched_pct': round(100.0 * float(slow.mean()), 4),
            'stretched_on_cpu_pct': round(100.0 * float(on.sum()) / max(int(slow.sum()), 1), 1)}


def domain_id(requested: int) -> int:
    """Return the runs' ROS domain: ``requested`` if >= 0, else $ROS_DOMAIN_ID, else private."""
    if requested >= 0:
        if requested > 232:
            raise ValueError(f'--domain-id {requested}: use 0..232 (Fast DDS port range)')
        return requested
    env = os.environ.get('ROS_DOMAIN_ID', '')
    if env.strip():
        return int(env)
    return 100 + os.getpid() % 100


def run_once(rate_hz, duration_s, args, workdir: Path, log, label=None) -> dict:
    """One benchmark run at ``rate_hz``; return its result dict (``label``: its progress)."""
    from rths_bringup.launcher import Launcher

    workdir.mkdir(parents=True, exist_ok=True)
    direct = not getattr(args, 'no_direct_delivery', False)   # (rths bench faults: no flag)
    divisor = getattr(args, 'rate_divisor', 1)
    config = write_config(workdir / 'config', rate_hz, duration_s, args.taps, args.model,
                          args.clock, args.executor, args.priority, args.cpus, args.gc,
                          watchdog_steps=args.watchdog_steps, margin_us=args.margin,
                          status_every=args.status_every, direct_delivery=direct,
                          rate_divisor=divisor)
    bag = None if args.no_bag else workdir / 'bag'
    timing = {name: (workdir / f'{name}_timing.npz').resolve()
              for name in ('bridge', 'numerical')}
    overrides = {name: {'timing_out': str(path)} for name, path in timing.items()}
    if bag is not None:
        overrides['recorder'] = {'nice': int(args.recorder_nice)}
        if args.recorder_cpus:
            overrides['recorder']['cpus'] = f'"{args.recorder_cpus}"'
    load_before = [round(x, 2) for x in os.getloadavg()]
    launcher = Launcher(config, bag=bag, overrides=overrides, out=log,
                        timeout_s=duration_s * 3 + 120, layout=args.layout,
                        progress_label=label or f'{rate_hz:g} Hz run')
    if getattr(args, 'live', False):  # one more reader of each loop topic: arm after it too
        readers = 3 if bag is not None and launcher.layout == 'processes' else 2
        for name in ('numerical', 'compensator', 'bridge'):
            launcher.overrides.setdefault(name, {})['wait_for_subscribers'] = readers
    from rths_live import live

    t0 = time.monotonic()
    with live.session(args, fs_hz=rate_hz):
        code = launcher.run()
    wall = time.monotonic() - t0
    if not all(p.exists() for p in timing.values()):
        raise OSError(f'the {rate_hz:g} Hz run failed (launcher exit {code}) before the nodes '
                      f'wrote their timing; see {getattr(log, "name", "the log")}')
    result = analyse(timing['bridge'], timing['numerical'], launcher.cpu_samples, bag, rate_hz)
    # a safety stop (e.g. the watchdog after consecutive misses) ends the run early
    result['run_completed'] = code == 0
    result.update(layout=args.layout, duration_s=duration_s, taps=args.taps, model=args.model,
                  clock=args.clock,
                  spin_margin_us=args.margin, status_every=args.status_every,
                  direct_delivery=direct, rate_divisor=divisor,
                  executor=args.executor, rt_priority=args.priority, cpus=args.cpus,
                  gc=args.gc, recorded=bag is not None, wall_s=round(wall, 1),
                  live_view=bool(getattr(args, 'live', False)),
                  recorder_nice=args.recorder_nice if bag is not None else None,
                  recorder_cpus=args.recorder_cpus if bag is not None else None,
                  loadavg_before=load_before,
                  loadavg_after=[round(x, 2) for x in os.getloadavg()])
    result['meets_targets'] = bool(_within_target(result)
                                   and result['latency_us_p99'] is not None
                                   and result['latency_us_p99'] < 1e6 / rate_hz)
    return result


def print_result(r: dict):
    """Print one run's result on two lines."""
    print(f"{r['layout']}, {r['rate_hz']:g} Hz x {r['duration_s']:g} s: {r['steps']} steps, "
          f"deadline misses {r['deadline_misses']} ({r['deadline_miss_pct']} %), latency "
          f"p50/p99/max {r['latency_us_p50']}/{r['latency_us_p99']}/{r['latency_us_max']} us, "
          f"loop p50/p99 {r['loop_us_p50']}/{r['loop_us_p99']} us (measurement to the "
          f"numerical node p50 {r.get('measurement_us_p50')}, its step "
          f"{r.get('numerical_us_p50')}, to the bridge {r['latency_us_p50']}), "
          f"tick late p99 {r['tick_late_us_p99']} us, "
          f"clock overruns {r['clock_overruns']} ({r['stalled_ticks']} ticks skipped), "
          f"cpu {r.get('cpu_pct')} %, load {r['loadavg_before']}"
          f"{'' if r['run_completed'] else ', RUN ABORTED (safety stop)'}", flush=True)
    if 'bag' in r:
        print(f"  recorder loss {r['bag']['recorder_loss']}, status accounting "
              f"{'consistent' if r['bag']['status_matches_bridge'] else 'INCONSISTENT'}",
              flush=True)


def cmd_bench_loop(args) -> int:
    """Run ``rths bench loop``: the floor, then one run or the --find-max series; write JSON."""
    if not args.rate > 0 or not args.duration > 0:
        raise ValueError('--rate and --duration must be > 0')
    keep = Path(args.keep) if args.keep else None
    with tempfile.TemporaryDirectory(prefix='rths-bench-loop-') as tmp:
        base = keep or Path(tmp)
        base.mkdir(parents=True, exist_ok=True)
        log_path = base / 'launch.log'
        print(f'rths bench loop: node logs in {log_path}' if keep else
              'rths bench loop: (use --keep DIR to keep logs, bag and timing files)', flush=True)
        report = {'machine': machine_info()}
        domain = domain_id(args.domain_id)
        os.environ['ROS_DOMAIN_ID'] = str(domain)   # the launcher's nodes inherit it
        report['ros_domain_id'] = domain
        if args.floor > 0:
            floor = platform_floor(1024.0 if args.find_max else args.rate, args.floor,
                                   max(args.priority, 1))
            floor['work'] = work_floor(args.floor, max(args.priority, 1))
            report['platform_floor'] = floor
            work = floor['work']
            print(f"platform floor ({args.floor:g} s empty SCHED_FIFO loop at "
                  f"{floor['rate_hz']:g} Hz): wake-up late p50/p99/max {floor['late_us_p50']}/"
                  f"{floor['late_us_p99']}/{floor['late_us_max']} us, "
                  f"{floor['late_gt_period_pct']} % later than a period; the same work each "
                  f"period (then {args.floor:g} s): p50 {work['chunk_us_p50']} us, "
                  f"{work['stretched_pct']} % of it over {STRETCH:g}x "
                  f"({work['stretched_on_cpu_pct']} % of those on the CPU)", flush=True)
        with open(log_path, 'w') as log:
            if args.find_max:
                runs = []
                best = None
                for i, rate in enumerate(FIND_MAX_RATES):
                    r = run_once(rate, args.duration, args, base / f'rate{rate}', log,
                                 f'{rate:g} Hz run [{i + 1}/{len(FIND_MAX_RATES)} rates]')
                    print_result(r)
                    runs.append(r)
                    if _within_target(r):
                        best = rate
                    elif not r['run_completed'] or r['deadline_miss_pct'] > GIVE_UP_PCT:
                        break  # far off: higher rates will not do better
                report.update(runs[0] if runs else {})
                report['runs'] = runs
                report['max_rate_hz'] = best
                print(f'highest rate with <= {MISS_TARGET_PCT} % of ticks missed or skipped: '
                      f"{f'{best} Hz' if best else 'none of the rates tried'}")
            else:
                r = run_once(args.rate, args.duration, args, base / 'run', log)
                print_result(r)
                report.update(r)
        report['machine']['loadavg_end'] = [round(x, 2) for x in os.getloadavg()]
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(report, indent=2))
        print(f'wrote {args.out}')
    return 0
