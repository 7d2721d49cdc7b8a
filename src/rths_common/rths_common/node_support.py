"""The thin ROS shell shared by the rths nodes: parameters, status messages, the spin loop.

Every node is created with ``automatically_declare_parameters_from_overrides``
so that all keys of its ``--params-file`` YAML become ROS parameters; the node
reads them as one flat dict and hands it to the plain-Python core
(``make_substructure``, ``load_compensator``, ``make_backend``), which
validates every key and reports bad ones by name.
"""

import gc
import importlib
import os
import signal
import sys
import threading
import time
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
import rclpy
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.logging import LoggingSeverity
from rclpy.node import Node
from rclpy.parameter import Parameter
from threadpoolctl import threadpool_limits

from rths_common import lifeline
from rths_common.params import check_spec
from rths_msgs.msg import LoopStatus

#: Parameters every rclpy node has; they are not passed to the plain-Python cores.
ROS_BUILTIN_PARAMS = ('use_sim_time', 'start_type_description_service')


class StepLogger:
    """A node's logger that costs microseconds, not milliseconds: for the loop's nodes.

    rclpy's ``logger.info`` looks for its caller with ``inspect.getframeinfo``,
    which reads the caller's source file: 0.5-2.5 ms a call on this project's VM
    (p99 3 ms, max 30 ms; with console, /rosout and the log file all switched off
    still 1.3 ms).  In a 1024 Hz loop that is a stall each time a node logs: the
    numerical node's progress line each simulated second skipped 1-2 ticks of the
    composed loop once a second (issue 28).  This logger takes its caller from
    :func:`sys._getframe` and calls the same rcutils function (15 us): the same
    output on the console, /rosout and the log file, the same severity threshold.
    rclpy's once/throttle filters are not offered.
    """

    def __init__(self, logger):
        self.logger = logger
        self.name = logger.name

    def _log(self, severity, message) -> bool:
        if not self.logger.is_enabled_for(severity):
            return False
        caller = sys._getframe(2)
        _rclpy.rclpy_logging_rcutils_log(severity, self.name, str(message),
                                         caller.f_code.co_name, caller.f_code.co_filename,
                                         caller.f_lineno)
        return True

    def debug(self, message) -> bool:
        """Log ``message`` at DEBUG."""
        return self._log(LoggingSeverity.DEBUG, message)

    def info(self, message) -> bool:
        """Log ``message`` at INFO."""
        return self._log(LoggingSeverity.INFO, message)

    def warning(self, message) -> bool:
        """Log ``message`` at WARN."""
        return self._log(LoggingSeverity.WARN, message)

    def error(self, message) -> bool:
        """Log ``message`` at ERROR."""
        return self._log(LoggingSeverity.ERROR, message)

    def get_child(self, name: str) -> 'StepLogger':
        """Return the child logger ``name`` (as rclpy's ``get_child``)."""
        return StepLogger(self.logger.get_child(name))


def make_node(name: str, schema: dict | None = None, defaults: dict | None = None,
              node_class=Node) -> Node:
    """Create a node whose parameters are everything its params file sets, described.

    ``schema`` (key -> :class:`rths_common.params.Spec`, from
    :func:`rths_common.params.node_schema`) describes them: each key it names gets
    a read-only descriptor with its type, description, choices and range (a value
    outside them raises ValueError naming the parameter), so ``ros2 param describe``
    shows them.  Keys of ``defaults`` (the node-level ``NODE_PARAMS``) that the
    file does not set are declared with their default.  A key the schema does not
    name is left to the core's check, which rejects it by name; no parameter can
    be added or changed at run time.  ``node_class``: ``Node`` or
    ``rclpy.lifecycle.LifecycleNode``.
    """
    node = node_class(name, automatically_declare_parameters_from_overrides=True)
    for key, spec in (schema or {}).items():
        if node.has_parameter(key):
            _describe(node, key, spec)
        elif defaults is not None and key in defaults:
            value = Parameter(key, value=defaults[key])
            node.declare_parameter(key, defaults[key], descriptor(key, value.type_, spec))
    return node


def _describe(node: Node, key: str, spec) -> None:
    """Check the file's value against ``spec``'s range and choices, then set the descriptor.

    An integer given for a float parameter (``fs_hz: 1024``) becomes a float.
    """
    value = node.get_parameter(key)
    check_spec(key, list(value.value) if _is_array(value.value) else value.value, spec)
    type_, alternative = value.type_, None
    if spec.range is not None and isinstance(spec.range[0], float):
        if type_ == Parameter.Type.INTEGER:
            type_ = Parameter.Type.DOUBLE
            alternative = Parameter(key, type_, float(value.value)).get_parameter_value()
        elif type_ == Parameter.Type.INTEGER_ARRAY:   # a per-channel list written as ints
            type_ = Parameter.Type.DOUBLE_ARRAY
            alternative = Parameter(key, type_, [float(v) for v in value.value]
                                    ).get_parameter_value()
    node.set_descriptor(key, descriptor(key, type_, spec), alternative)


def _is_array(value) -> bool:
    return isinstance(value, (list, tuple)) or type(value).__name__ == 'array'


def descriptor(key: str, type_: Parameter.Type, spec) -> ParameterDescriptor:
    """Return the read-only descriptor of ``key``: type, description and ``spec``'s range."""
    out = ParameterDescriptor(name=key, type=type_.value, description=spec.text(),
                              read_only=True)
    if spec.range is not None:
        low, high = spec.range
        if type_ == Parameter.Type.INTEGER:
            out.integer_range = [IntegerRange(from_value=int(low), to_value=int(high), step=0)]
        elif type_ in (Parameter.Type.DOUBLE, Parameter.Type.DOUBLE_ARRAY):
            out.floating_point_range = [FloatingPointRange(from_value=float(low),
                                                           to_value=float(high), step=0.0)]
    return out


def parameters(node: Node) -> dict:
    """All parameters of ``node`` as a flat ``{name: python value}`` dict."""
    out = {}
    # rclpy annotates the values as parameter values; they are Parameter objects
    by_name: dict[str, Any] = node.get_parameters_by_prefix('')
    for name, param in by_name.items():
        if name in ROS_BUILTIN_PARAMS or name.startswith('qos_overrides.'):
            continue
        value = param.value
        if _is_array(value):
            value = list(value)
        out[name] = value
    return out


def param(params: dict, name: str, default):
    """``params[name]`` if set, else ``default``, with the default's type enforced."""
    value = params.get(name, default)
    if default is not None and not isinstance(value, type(default)):
        if isinstance(default, float) and isinstance(value, int):
            return float(value)
        raise ValueError(f'parameter {name!r} must be {type(default).__name__}, '
                         f'got {value!r}; fix it in the params file')
    return value


def now_ns() -> int:
    """Wall-clock time [ns] used for message stamps (system clock, comparable across processes)."""
    return time.time_ns()


def stamp(header, t_ns: int):
    """Set ``header.stamp`` from nanoseconds."""
    header.stamp.sec, header.stamp.nanosec = divmod(t_ns, 1_000_000_000)


def stamp_ns(header) -> int:
    """Nanoseconds of ``header.stamp``."""
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


class StepClock:
    """Per-step timing bookkeeping of a node (period, compute time, deadline misses)."""

    def __init__(self):
        self.last_ns = None
        self.misses = 0

    def period_us(self, t_ns: int) -> float:
        """Time since the previous step [us] (0 for the first), and remember ``t_ns``."""
        period = 0.0 if self.last_ns is None else (t_ns - self.last_ns) * 1e-3
        self.last_ns = t_ns
        return period


def parse_cpus(spec: str) -> set:
    """CPU set of an affinity spec such as ``'1'``, ``'0,1'`` or ``'0-1'`` ('' = all CPUs)."""
    cpus: set[int] = set()
    for part in str(spec).replace(' ', '').split(','):
        if not part:
            continue
        lo, _, hi = part.partition('-')
        try:
            cpus.update(range(int(lo), int(hi or lo) + 1))
        except ValueError:
            raise ValueError(f'parameter cpus = {spec!r} is not a CPU list such as "1" or '
                             '"0,1"') from None
    return cpus


#: Latency settings every loop node takes (realtime mode); see :func:`tune_process`.
#: -1 / 'auto': the realtime defaults of :func:`tuning` (nothing in lock-step).
TUNING_PARAMS = {'rt_priority': -1, 'cpus': '', 'gc': 'auto'}

#: The run identity every loop node takes (rths_common.transport; '' when started by hand).
RUN_PARAMS = {'run_id': ''}

#: SCHED_FIFO priority of each loop node in realtime mode unless ``rt_priority`` is set
#: (0 = normal scheduling): the bridge (the clock) above the two others.  Measured on the
#: 2-core VM under load: without SCHED_FIFO about half of the 1024 Hz deadlines are missed.
RT_PRIORITY = {'bridge': 80, 'compensator': 79, 'numerical': 79}


def tuning(own: dict, node_name: str) -> tuple:
    """``(rt_priority, cpus, gc_mode)`` of a node from its params, 'auto' values resolved.

    In realtime mode the defaults are SCHED_FIFO at :data:`RT_PRIORITY` and
    ``gc: freeze``; in lock-step they are normal scheduling and the default GC.
    """
    realtime = own.get('mode') == 'realtime'
    prio = int(own.get('rt_priority', -1))
    if prio < 0:
        prio = RT_PRIORITY.get(node_name, 79) if realtime else 0
    gc_mode = own.get('gc', 'auto')
    if gc_mode == 'auto':
        gc_mode = 'freeze' if realtime else 'default'
    return prio, own.get('cpus', ''), gc_mode


#: Environment variables a BLAS library reads for its thread count when it is loaded.
BLAS_THREADS_ENV = ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS')


def tune_process(rt_priority: int = 0, cpus: str = '', gc_mode: str = 'default') -> str:
    """Apply the latency settings of a loop process to every thread it has; describe them.

    * ``rt_priority`` > 0: SCHED_FIFO at that priority for every thread of the
      process (the DDS receive threads included: they deliver the messages).
      Refused (no CAP_SYS_NICE, container without RT budget): the threads stay
      SCHED_OTHER and the description says so; the run goes on.
    * ``cpus``: CPU affinity (``'1'``, ``'0,1'``; '' = leave as is).
    * with either: BLAS (OpenBLAS, numpy's and SciPy's) computes on this thread
      only.  Its worker threads wait for work by spinning; at the loop's FIFO
      priority on the loop's CPU they never let the waiting thread run again (a
      node with ``cpus: '1'`` hung in its configure step, issue 28), and the
      loop's vectors are too short to gain from them.
    * ``gc_mode``: 'default' (leave the collector alone), 'freeze' (collect once,
      then move every object created so far out of the collector's sight so
      collections are short) or 'disable' (freeze and switch automatic
      collection off: no collection pause can hit a step; the loop code creates
      no reference cycles, so memory stays flat).

    Call it after the node and its publishers/subscriptions exist (their threads
    are created then) and again when the loop starts.
    """
    parts = []
    if cpus or rt_priority > 0:
        threadpool_limits(1)                 # the BLAS libraries loaded so far
        os.environ.update({k: '1' for k in BLAS_THREADS_ENV})     # and those loaded later
        parts.append('BLAS on 1 thread')
    tids = [int(t) for t in os.listdir('/proc/self/task')]
    if cpus:
        cpuset = parse_cpus(cpus)
        try:
            for tid in tids:
                os.sched_setaffinity(tid, cpuset)
            parts.append(f'cpus {sorted(cpuset)}')
        except OSError as err:
            parts.append(f'affinity {sorted(cpuset)} refused ({err})')
    if rt_priority > 0:
        try:
            for tid in tids:
                os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(int(rt_priority)))
            parts.append(f'SCHED_FIFO {int(rt_priority)} ({len(tids)} threads)')
        except OSError as err:
            parts.append(f'SCHED_OTHER (SCHED_FIFO {rt_priority} refused: {err})')
    if gc_mode not in ('default', 'freeze', 'disable'):
        raise ValueError(f"parameter gc = {gc_mode!r}: use 'default', 'freeze' or 'disable'")
    if gc_mode in ('freeze', 'disable'):
        gc.collect()
        gc.freeze()
        if gc_mode == 'disable':
            gc.disable()
    parts.append(f'gc {gc_mode}')
    return ', '.join(parts)


def status_msg(node_name: str, step: int, *, period_us=0.0, compute_us=0.0, latency_us=-1.0,
               missed=False, misses=0, safety_state=LoopStatus.SAFETY_OK, fault='',
               frame_id: str = '') -> LoopStatus:
    """Build a LoopStatus message (arrays/strings set through the constructor, as is fastest)."""
    msg = LoopStatus(node=node_name, step=int(step), step_period_us=float(period_us),
                     compute_us=float(compute_us), latency_us=float(latency_us),
                     deadline_missed=bool(missed), deadline_misses=int(misses),
                     safety_state=int(safety_state), fault=fault)
    msg.header.frame_id = frame_id
    stamp(msg.header, now_ns())
    return msg


def log_foreign(log, transport, topic: str):
    """Log a message of another run dropped from ``topic`` (the first 5, then every 1000th)."""
    n = transport.foreign
    if n <= 5 or n % 1000 == 0:
        log.warning(f'{topic}: {transport.foreign_text()}; this node acts only on run '
                    f'{transport.run_id or "(none)"}')


def make_executor(kind: str = 'events'):
    """Return an executor: 'events' (rclpy.experimental.EventsExecutor) or 'single'."""
    if kind == 'events':
        return EventsExecutor()
    if kind == 'single':
        return SingleThreadedExecutor()
    raise ValueError(f"unknown executor {kind!r}; use 'events' or 'single'")


#: The signal (SIGINT/SIGTERM number) that stopped the last spin loop, None if none did.
STOP_SIGNAL = {'signum': None}


def _as_nodes(node) -> list:
    """``node`` as a list: one node, or the nodes of a composed process (a list or tuple)."""
    return list(node) if isinstance(node, (list, tuple)) else [node]


def _spin_signals():
    """Catch SIGINT/SIGTERM into a flag (kept in :data:`STOP_SIGNAL`); return (flag, previous)."""
    stop = {'signal': None}

    def on_signal(signum, _frame):
        stop['signal'] = STOP_SIGNAL['signum'] = signum

    STOP_SIGNAL['signum'] = None
    return stop, {s: signal.signal(s, on_signal) for s in (signal.SIGTERM, signal.SIGINT)}


def spin_until_done(node, executor, is_done=lambda: False, poll_s: float = 0.05) -> bool:
    """Spin ``node`` (or a list of nodes) with ``spin_once`` until ``is_done()``, SIGINT or SIGTERM.

    Returns True if the run finished (``is_done``), False if it was stopped by a
    signal (its number in :data:`STOP_SIGNAL`).  (``EventsExecutor.spin()``
    ignores SIGTERM and can starve timers; a ``spin_once`` loop does not.)
    """
    stop, previous = _spin_signals()
    nodes = _as_nodes(node)
    for n in nodes:
        executor.add_node(n)
    try:
        while stop['signal'] is None and rclpy.ok() and not is_done():
            executor.spin_once(timeout_sec=poll_s)
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        for n in nodes:
            executor.remove_node(n)
    return is_done()


def spin_clocked(node, executor, next_due_ns, tick, is_done=lambda: False,
                 poll_s: float = 0.05, margin_us: float = 0.0, nap_us: float = 20.0,
                 ready=None, drain: int = 16, quiet=None, pass_ns: int = 1_000_000) -> bool:
    """Spin ``node`` (or nodes); call ``tick()`` whenever ``next_due_ns()`` (monotonic ns) is due.

    The realtime clock of the actuator bridge without a second thread: between
    ticks the loop sits in ``executor.spin_once`` with a timeout that ends at the
    next tick (callbacks, i.e. arriving commands, run meanwhile); when the tick
    is due, events already queued are handled first (``spin_once(0)``) so a
    command that arrived just before its tick is used.  ``next_due_ns()`` returns
    None while there is nothing to tick.  Ends like :func:`spin_until_done`.

    ``margin_us`` > 0: the wait in ``spin_once`` ends that much before the tick
    (its wake-up is late by ~50-200 us on a loaded machine); the rest of the
    time is spent polling (``spin_once(0)``) with naps of ``nap_us`` (sleeping,
    so the DDS threads get the CPU), which also hands over a command arriving
    in that window at once.

    ``ready`` (composed layout: every node in this loop): at the tick, while
    ``ready()`` is False, up to ``drain`` more queued events are handled
    first: the command of the step is then still on its way through this
    very loop (the thread came late), not missing.

    ``quiet`` (the container's direct delivery): while ``quiet()`` and
    ``ready()`` are True, the loop messages come by direct calls and none
    crosses DDS, so the executor has nothing the tick needs.  The loop then
    sleeps to the tick instead of waiting in the executor, and gives the
    executor one pass (``spin_once(0)``) each ``pass_ns`` for everything else
    (services, timers, the emergency-stop topic, other publishers' messages);
    ``rclpy.ok()`` (2 us) is asked at those passes only.
    An executor call costs about 35 us of CPU, and its timed wait ends about
    90 us late at normal priority (2-core VM, 2026-11-28), where a 4096 Hz
    period is 244 us.
    """
    margin_ns = int(margin_us * 1e3)
    nap_s = nap_us * 1e-6
    stop, previous = _spin_signals()
    nodes = _as_nodes(node)
    for n in nodes:
        executor.add_node(n)
    last_pass = time.monotonic_ns()     # the executor's last pass
    try:
        while stop['signal'] is None and not is_done():
            due = next_due_ns()
            if due is not None and quiet is not None and quiet() and ready():
                now = time.monotonic_ns()
                if now - last_pass >= pass_ns:
                    if not rclpy.ok():  # (2 us: asked at the executor's passes only)
                        break
                    executor.spin_once(timeout_sec=0.0)
                    last_pass = time.monotonic_ns()
                    continue
                if due > now:
                    time.sleep(min((due - now) * 1e-9, poll_s))
                    if time.monotonic_ns() < due:
                        continue        # (a tick further than poll_s away: look again)
                tick()
                continue
            if not rclpy.ok():
                break
            if due is None:
                executor.spin_once(timeout_sec=poll_s)
                continue
            wait_ns = due - time.monotonic_ns()
            if wait_ns > margin_ns:
                executor.spin_once(timeout_sec=min((wait_ns - margin_ns) * 1e-9, poll_s))
            elif wait_ns > 0:
                executor.spin_once(timeout_sec=0.0)
                time.sleep(min(wait_ns * 1e-9, nap_s))
            else:
                executor.spin_once(timeout_sec=0.0)
                if ready is not None:
                    for _ in range(drain):
                        if ready():
                            break
                        executor.spin_once(timeout_sec=0.0)
                tick()
            last_pass = time.monotonic_ns()
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        for n in nodes:
            executor.remove_node(n)
    return is_done()


class TickThread:
    """A dedicated clock thread: calls ``tick()`` at ``next_due_ns()`` (monotonic ns).

    Sleeps with ``time.sleep`` (clock_nanosleep; no timer slack under
    SCHED_FIFO) up to the due time; ``next_due_ns()`` None means idle (polls
    every ``poll_s``).  ``tick`` runs in this thread, so it must only touch
    state the executor thread hands over atomically (one attribute assignment).
    """

    def __init__(self, next_due_ns, tick, poll_s: float = 0.01):
        self.next_due_ns = next_due_ns
        self.tick = tick
        self.poll_s = poll_s
        self.running = True
        self.error: Exception | None = None
        self.thread = threading.Thread(target=self._run, name='rths-clock', daemon=True)

    def start(self):
        """Start the clock thread; return self."""
        self.thread.start()
        return self

    def _run(self):
        try:
            while self.running:
                due = self.next_due_ns()
                if due is None:
                    time.sleep(self.poll_s)
                    continue
                wait_ns = due - time.monotonic_ns()
                if wait_ns > 0:
                    time.sleep(wait_ns * 1e-9)
                    continue
                self.tick()
        except Exception as err:  # noqa: BLE001 - reported by the owner after join()
            self.error = err

    def stop(self):
        """Stop the clock thread and wait for it (2 s at most)."""
        self.running = False
        self.thread.join(timeout=2.0)


def message_class(msgtype: str):
    """Python class of a message type given as ``pkg/msg/Name``."""
    package, kind, name = msgtype.split('/')
    return getattr(importlib.import_module(f'{package}.{kind}'), name)


#: Longest single wait of :func:`flush` for acknowledgements [s].
FLUSH_SLICE_S = 0.02


def flush(publishers, timeout_s: float = 2.0) -> bool:
    """Wait until every reliable reader acknowledged what ``publishers`` sent.

    Call before a node exits: a process that ends with unacknowledged samples
    takes them (and its transient-local history) with it, so a lagging
    recorder would lose the last steps of a run.  Once the launcher died the
    wait is at most ``lifeline.LOST_FLUSH_S``: the readers that died with it
    never answer, and the run's processes must be gone within a second.
    ``timeout_s`` is each publisher's share, as when they were waited for one
    after another (the whole wait is at most ``timeout_s`` times their number);
    it waits in slices of FLUSH_SLICE_S so that a launcher dying meanwhile cuts
    it to ``lifeline.LOST_FLUSH_S`` (a bridge flushing after its safety stop
    outlived a killed launcher by 2 s).
    """
    t0 = time.monotonic()
    pending = list(publishers)
    budget = timeout_s * max(len(pending), 1)
    while pending:
        limit = min(budget, lifeline.LOST_FLUSH_S) if lifeline.lost() else budget
        left = limit - (time.monotonic() - t0)
        if left <= 0:
            return False
        wait = Duration(nanoseconds=int(min(left, FLUSH_SLICE_S) * 1e9))
        pending = [pub for pub in pending if not pub.wait_for_all_acked(wait)]
    return True


def wait_for_readers(node, publisher, wanted: int, timeout_s: float = 60.0) -> None:
    """Spin ``node`` until ``publisher`` has matched ``wanted`` readers (ValueError on timeout).

    The loop nodes call this before subscribing to their input, so the chain
    arms from its end: the bridge subscribes once the numerical node and the
    recorder read its measurements, the compensator once the bridge and the
    recorder read its commands, and the numerical node starts once the
    compensator and the recorder read its interface displacement.  Graph
    counts seen from one process (``count_subscribers``) do not prove that
    another process's writer has matched: DDS discovery between participants
    can take seconds, longer than a transient-local history covers.
    """
    if wanted <= 0:
        return
    t_end = time.monotonic() + timeout_s
    while publisher.get_subscription_count() < wanted:
        if lifeline.lost():
            raise ValueError(f'{node.get_name()}: {lifeline.describe()} before the graph '
                             'connected')
        if time.monotonic() > t_end:
            raise ValueError(f'{node.get_name()}: only {publisher.get_subscription_count()} of '
                             f'{wanted} reader(s) of {publisher.topic_name} matched within '
                             f'{timeout_s:g} s; is the rest of the graph running?')
        rclpy.spin_once(node, timeout_sec=0.02)


def gid_text(gid) -> str:
    """Text form of a DDS endpoint gid (``TopicEndpointInfo.endpoint_gid``): dotted hex bytes."""
    return '.'.join(format(int(x), '02x') for x in gid)


def own_writer_gid(node, topic: str) -> str:
    """Gid text of ``node``'s own publisher on ``topic`` ('' if the graph does not show it yet).

    Sent in ``header.frame_id`` of the lock-step loop messages so the receiver can
    check who sent each one (rclpy's message info carries no publisher gid).
    """
    for info in node.get_publishers_info_by_topic(topic):
        if (info.node_name == node.get_name()
                and info.node_namespace == node.get_namespace()):
            return gid_text(info.endpoint_gid)
    return ''


def params_file_of(argv) -> str:
    """``'PATH: '`` for the ``--params-file PATH`` of a node's argv ('' if none), for errors."""
    args = list(sys.argv if argv is None else argv)
    files = [args[i + 1] for i, a in enumerate(args[:-1]) if a == '--params-file']
    return f'params file {files[-1]}: ' if files else ''
