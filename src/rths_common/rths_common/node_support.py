"""The thin ROS shell shared by the rths nodes: parameters, status messages, the spin loop.

Every node is created with ``automatically_declare_parameters_from_overrides``
so that all keys of its ``--params-file`` YAML become ROS parameters; the node
reads them as one flat dict and hands it to the plain-Python core
(``make_substructure``, ``load_compensator``, ``make_backend``), which
validates every key and reports bad ones by name.
"""

import signal
import time

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from rths_msgs.msg import LoopStatus


#: Parameters every rclpy node has; they are not passed to the plain-Python cores.
ROS_BUILTIN_PARAMS = ('use_sim_time', 'start_type_description_service')


def make_node(name: str) -> Node:
    """Create a node whose parameters are everything its params file sets."""
    return Node(name, automatically_declare_parameters_from_overrides=True,
                allow_undeclared_parameters=True)


def parameters(node: Node) -> dict:
    """All parameters of ``node`` as a flat ``{name: python value}`` dict."""
    out = {}
    for name, param in node.get_parameters_by_prefix('').items():
        if name in ROS_BUILTIN_PARAMS or name.startswith('qos_overrides.'):
            continue
        value = param.value
        if isinstance(value, (list, tuple)) or type(value).__name__ == 'array':
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


def status_msg(node_name: str, step: int, *, period_us=0.0, compute_us=0.0, latency_us=-1.0,
               missed=False, misses=0, safety_state=LoopStatus.SAFETY_OK, fault='') -> LoopStatus:
    """Build a LoopStatus message (arrays/strings set through the constructor, as is fastest)."""
    msg = LoopStatus(node=node_name, step=int(step), step_period_us=float(period_us),
                     compute_us=float(compute_us), latency_us=float(latency_us),
                     deadline_missed=bool(missed), deadline_misses=int(misses),
                     safety_state=int(safety_state), fault=fault)
    stamp(msg.header, now_ns())
    return msg


def make_executor(kind: str = 'events'):
    """Return an executor: 'events' (rclpy.experimental.EventsExecutor) or 'single'."""
    if kind == 'events':
        from rclpy.experimental import EventsExecutor
        return EventsExecutor()
    if kind == 'single':
        return SingleThreadedExecutor()
    raise ValueError(f"unknown executor {kind!r}; use 'events' or 'single'")


def spin_until_done(node, executor, is_done=lambda: False, poll_s: float = 0.05) -> bool:
    """Spin ``node`` with ``spin_once`` until ``is_done()``, SIGINT or SIGTERM.

    Returns True if the run finished (``is_done``), False if it was stopped by a
    signal.  (``EventsExecutor.spin()`` ignores SIGTERM and can starve timers;
    a ``spin_once`` loop does not.)
    """
    stop = {'signal': None}

    def on_signal(signum, _frame):
        stop['signal'] = signum

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGTERM, signal.SIGINT)}
    executor.add_node(node)
    try:
        while stop['signal'] is None and rclpy.ok() and not is_done():
            executor.spin_once(timeout_sec=poll_s)
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        executor.remove_node(node)
    return is_done()


def message_class(msgtype: str):
    """Python class of a message type given as ``pkg/msg/Name``."""
    import importlib

    package, kind, name = msgtype.split('/')
    return getattr(importlib.import_module(f'{package}.{kind}'), name)


def flush(publishers, timeout_s: float = 2.0) -> bool:
    """Wait until every reliable reader acknowledged what ``publishers`` sent.

    Call before a node exits: a process that ends with unacknowledged samples
    takes them (and its transient-local history) with it, so a lagging
    recorder would lose the last steps of a run.
    """
    from rclpy.duration import Duration

    ok = True
    for pub in publishers:
        ok = pub.wait_for_all_acked(Duration(nanoseconds=int(timeout_s * 1e9))) and ok
    return ok
