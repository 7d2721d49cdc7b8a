"""Composed layout: the bridge, compensator and numerical nodes in one process, one executor.

``ros2 run rths_bringup container --ros-args --params-file bridge.yaml
--params-file compensator.yaml --params-file numerical.yaml``

The ROS 2 composition convention with the project's own node classes: each
node keeps its package, class, name, parameters (a params file is keyed by
node name, so the three files given together reach their own nodes), topics
and lifecycle services; the container constructs them in one process
(numerical first, so the chain's readers exist before the bridge and the
compensator wait for them) and spins the three on one executor.  In realtime
the bridge's ticks drive that spin loop: it is the clock of the process.

The run ends when the numerical node finishes (exit 0), when the bridge's
safety supervisor stopped the actuator (exit 3; also after the launcher died:
:mod:`rths_common.lifeline`), on SIGINT/SIGTERM (128 +
the signal, after every node has flushed and saved what it keeps), or when the
numerical node failed (exit 1); bad parameters exit 2 naming the node and its
params file.  The last line names the node that ended the run
(``container: ended by NODE ...``), which the launcher reports.

``--tee-fd N`` (given by the launcher with a bag): every message the three
nodes publish on the recorded topics is also copied into the pipe ``N``
(:mod:`rths_common.tee`) for the recorder process, so the bag holds every
step and recording never shares this process's executor.  The queue in front
of the pipe holds the whole run (``TEE_RECORDS_PER_STEP`` records a step);
records beyond it are dropped and counted, and the run then says
``BAG INCOMPLETE``.

Realtime recipe (parameters of the bridge: ``rt_priority``, ``cpus``, ``gc``):
SCHED_FIFO for every thread of the process (a warning and normal scheduling
where refused), memory locked (``mlockall``; refused: a warning), the garbage
collector frozen after start-up (:func:`rths_common.node_support.tune_process`).
"""

import argparse
from collections import deque
import ctypes
import os
import sys

import rclpy
from rclpy.utilities import remove_ros_args

from rths_actuator_bridge.node import BridgeNode
from rths_common import lifeline, topics, yamlfile
from rths_common import node_support as ns
from rths_common.tee import Tee, TeePublisher, enlarge_pipe
from rths_compensator.node import CompensatorNode
from rths_numerical.node import NumericalNode

EXIT_FAILED = 1
EXIT_BAD_PARAMS = 2
EXIT_SAFETY_STOP = 3
#: Records the recording tee queues per loop step, at most (3 loop messages, 3 statuses,
#: the specimen channels), plus slack: the queue is sized for the whole run.
TEE_RECORDS_PER_STEP = 8
TEE_SLACK_RECORDS = 100_000
_MCL_CURRENT, _MCL_FUTURE = 1, 2
#: The nodes of the container in construction order: numerical first, it subscribes to the
#: measurements the bridge waits to be read.
NODE_NAMES = ('numerical', 'bridge', 'compensator')
#: The loop topics delivered by direct calls between the container's nodes (LocalPublisher).
DIRECT_TOPICS = (topics.MEASUREMENT, topics.INTERFACE_DISPLACEMENT, topics.COMMAND)
#: How often [messages] a LocalPublisher looks whether a reader outside the container matched ...
EXTERNAL_CHECK_STEPS = 256
#: ... and how many of its last messages its own DDS readers recognise as copies.
RECENT = 64


def parse_args(argv) -> argparse.Namespace:
    """Parse the container's own options (everything outside ``--ros-args``)."""
    p = argparse.ArgumentParser(prog='container', description=__doc__.split('\n')[0])
    p.add_argument('--tee-fd', type=int, default=-1,
                   help='pipe to copy every recorded message into (the recorder reads it)')
    return p.parse_args(remove_ros_args(args=list(argv))[1:])


def params_files(argv) -> list:
    """Return the ``--params-file`` paths of ``argv``."""
    args = list(argv)
    return [args[i + 1] for i, a in enumerate(args[:-1]) if a == '--params-file']


def params_file_of(argv, node_name: str) -> str:
    """``'params file PATH: '`` of the file with a ``node_name`` section ('' if none)."""
    for path in params_files(argv):
        try:
            if node_name in (yamlfile.load(path) or {}):
                return f'params file {path}: '
        except (OSError, ValueError):
            continue
    return ''


def check_sections(argv) -> None:
    """Refuse a params-file section that no node of the container reads (a misspelt node name).

    A ROS node ignores the sections of other nodes, so a typo there would run the
    node on its defaults without a word.  ``/**`` (every node) is allowed.
    """
    known = NODE_NAMES
    for path in params_files(argv):
        try:
            doc = yamlfile.load(path) or {}
        except OSError as err:
            raise ValueError(f'params file {err}') from None
        for key in (doc if isinstance(doc, dict) else {}):
            if str(key).strip('/') not in (*known, '**'):
                raise ValueError(f'params file {path}: section {key!r} is no node of the '
                                 f'container; name one of {", ".join(known)} (or /**)')


def lock_memory() -> str:
    """``mlockall(MCL_CURRENT | MCL_FUTURE)``: no page fault in the step path; describe it."""
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.mlockall(_MCL_CURRENT | _MCL_FUTURE) == 0:
        return 'memory locked'
    return f'memory not locked (mlockall refused: {os.strerror(ctypes.get_errno())})'


def tee_publishers(shells, fd: int, n_steps: int):
    """Wrap every recorded publisher of ``shells`` in a tee to ``fd``; return the Tee."""
    enlarge_pipe(fd)
    tee = Tee(fd, capacity=TEE_RECORDS_PER_STEP * n_steps + TEE_SLACK_RECORDS)
    for shell in shells:
        for attr in ('pub', 'status_pub', 'specimen_pub', 'coef_pub', 'stability_pub',
                     'controller_pub'):
            publisher = getattr(shell, attr, None)
            if publisher is not None:
                setattr(shell, attr, TeePublisher(publisher, tee))
    return tee


class LocalPublisher:
    """A loop publisher that hands each message to the container's own readers directly.

    Composed layout, realtime, the bridge's loop clock (``direct_delivery``): the
    three nodes' loop messages need not cross DDS.  Each reader's callback is
    called with the very message (CDR bytes) the publisher was given, in the
    ticking thread, in the order DDS gave (:class:`DirectBus`): a hop costs a call
    instead of a DDS write, an executor event and a take (1024 Hz on the 2-core VM
    of 2026-11-28: the round trip p50 340 -> 231 us, the process's CPU 49 -> 37 %).
    DDS still carries the message when a reader outside the container matched (the
    live view, a recorder over DDS; looked at every :data:`EXTERNAL_CHECK_STEPS`
    messages); the container's own DDS readers then drop that copy
    (:meth:`from_dds`: one of the last :data:`RECENT` messages), while a message of
    another publisher reaches them as before (another run's, a second source of
    commands: refused and counted).  With no ``callbacks`` (a status publisher) it
    only gates the DDS write on a reader outside.
    """

    def __init__(self, publisher, callbacks, local_readers: int, bus: 'DirectBus'):
        self.publisher = publisher
        self.bus = bus
        self.topic_name = publisher.topic_name
        self.callbacks = tuple(callbacks)
        self.local_readers = local_readers
        self.recent = deque(maxlen=RECENT)
        self.external = True
        self.count = 0

    def publish(self, msg):
        """Deliver ``msg`` to the container's readers; over DDS too if others listen."""
        if self.count % EXTERNAL_CHECK_STEPS == 0:
            self.external = self.publisher.get_subscription_count() > self.local_readers
        self.count += 1
        if self.external:
            if self.callbacks:
                self.recent.append(msg)
            self.publisher.publish(msg)
        if self.callbacks:
            self.bus.deliver(self.callbacks, msg)

    def from_dds(self, callback):
        """Return the DDS callback of a container reader: ``callback``, but not for our copies."""
        recent = self.recent

        def reader(msg):
            if msg not in recent:
                callback(msg)
        return reader

    def __getattr__(self, name):
        return getattr(self.publisher, name)


class DirectBus:
    """The order DDS gave: every reader of a message gets it before what they publish moves.

    A message's readers are called one after the other from a queue, and a message
    one of them publishes waits its turn behind them, as the executor took the
    events in the order they came.  Called in depth instead, the numerical node's
    step k + 1 would reach the compensator before the compensator had read
    measurement k (the feedback of the pi_lead controller one step older: it went
    unstable in test_realtime_methods).
    """

    def __init__(self):
        self.queue: deque = deque()
        self.draining = False

    def deliver(self, callbacks, msg):
        """Queue ``msg`` for each of ``callbacks``; call them in order unless already doing so."""
        queue = self.queue
        for callback in callbacks:
            queue.append((callback, msg))
        if self.draining:
            return
        self.draining = True
        try:
            while queue:
                callback, item = queue.popleft()
                callback(item)
        except BaseException:
            queue.clear()          # a reader failed: what it would have led to is void
            raise
        finally:
            self.draining = False


def direct_delivery(shells) -> list:
    """Wire the loop publishers of ``shells`` to their readers in the process; the publishers.

    The status publishers become LocalPublishers with no reader in the process: they
    write to DDS only while a reader outside listens (the bag gets them from the
    recording tee).  On the 2-core VM the ticking thread's CPU per tick fell by 24 us
    at 1024 Hz and 48 us at 2048 Hz (docs/bench/loop_status_gate_20261129.json).
    """
    readers: dict = {}
    for shell in shells:
        for sub in shell.node.subscriptions:
            if sub.topic_name in DIRECT_TOPICS:
                readers.setdefault(sub.topic_name, []).append(sub)
    wired = []
    bus = DirectBus()
    for shell in shells:
        publisher = getattr(shell, 'pub', None)
        subs = readers.get(getattr(publisher, 'topic_name', None))
        if not subs:
            continue
        local = LocalPublisher(publisher, [sub.callback for sub in subs], len(subs), bus)
        for sub in subs:
            sub.callback = local.from_dds(sub.callback)
        shell.pub = local
        wired.append(local)
    for shell in shells:
        status = getattr(shell, 'status_pub', None)
        if status is not None:
            shell.status_pub = LocalPublisher(status, (), 0, bus)
    return wired


class Container:
    """The three loop nodes of a run, constructed in this process."""

    def __init__(self, argv):

        check_sections(argv)
        self.shells = {}
        classes = {'numerical': NumericalNode, 'bridge': BridgeNode,
                   'compensator': CompensatorNode}
        for name in NODE_NAMES:
            try:
                self.shells[name] = classes[name]()
            except ValueError as err:
                raise ValueError(f'{name} node: {params_file_of(argv, name)}{err}') from None
        self.numerical = self.shells['numerical']
        self.bridge = self.shells['bridge']
        self.compensator = self.shells['compensator']
        self.log = self.bridge.node.get_logger().get_child('container')
        self.tee = None

    @property
    def nodes(self) -> list:
        """Return the rclpy nodes of the three shells."""
        return [shell.node for shell in self.shells.values()]

    def done(self) -> bool:
        """Return True once the numerical node finished (or failed) or the bridge stopped.

        (The bridge stopped: a safety stop, or its managed node was shut down.)  Once
        the launcher died, only the bridge's safe stop ends the run.
        """
        if self.bridge.launcher_lost:
            return self.bridge.stopped or self.bridge.finalized
        return self.numerical.finished or self.bridge.stopped or self.bridge.finalized

    def tune(self) -> str:
        """Realtime: the bridge's latency settings for the whole process, memory locked."""
        if self.bridge.lockstep:
            return 'lock-step: normal scheduling'
        text = ns.tune_process(*ns.tuning(self.bridge.own, 'bridge'))
        return f'{text}, {lock_memory()}'

    def run(self) -> int:
        """Spin the three nodes until the run is over; finish each; the exit code."""
        executor = ns.make_executor(self.bridge.own['executor'])
        self.log.info(f'composed: {", ".join(self.shells)} in one process on one '
                      f"{self.bridge.own['executor']} executor; {self.tune()}")
        finished = self.bridge.spin(executor, self.nodes, self.done)
        signum = None if finished else ns.STOP_SIGNAL['signum']
        # the bridge first: an external actuator ramps to its safe position right after the
        # record, not after the others' bookkeeping (the response through the recording tee,
        # the history and timing files): that left its controller without a command for
        # 19-21 ms after a 10 s run at 1024 Hz (test_container_finish.py); theirs still run if
        # the bridge's finish fails (the history file is the run's record too)
        try:
            self.bridge.finish_run()
        finally:
            self.numerical.finish_run(self.numerical.finished)
            self.compensator.finish_run()
        self.close_tee()
        if self.bridge.stopped:
            print('container: ended by bridge (exit code 3: safety stop)', flush=True)
            return EXIT_SAFETY_STOP
        if self.numerical.failed:
            print('container: ended by numerical (exit code 1: the run failed)', flush=True)
            return EXIT_FAILED
        if signum is not None:
            print(f'container: ended by signal {signum}', flush=True)
            return 128 + signum
        print('container: ended by numerical (run finished)', flush=True)
        return 0

    def close_tee(self):
        """Hand the last records to the recorder; say loudly if any were dropped."""
        if self.tee is None:
            return
        stats = self.tee.close()
        text = (f"recording tee: {stats['records']} message(s) to the recorder, "
                f"{stats['dropped']} dropped, largest queue {stats['peak_queue']}")
        if stats['dropped']:
            self.log.error(f'{text}: BAG INCOMPLETE {stats["error"]}')
        else:
            self.log.info(text)


def main(argv=None, prepare=None) -> int:
    """Entry point of ``ros2 run rths_bringup container``.

    ``prepare(container)``, if given, is called once the nodes (and the recording
    tee) are set up, before the run.
    """
    lifeline.bind()       # its launcher's death: the bridge's safe stop, exit
    argv = list(sys.argv if argv is None else argv)
    opts = parse_args(argv)
    rclpy.init(args=argv)
    container = None
    try:
        container = Container(argv)
        own = container.bridge.own
        if not container.bridge.lockstep and own['clock'] == 'loop' and own['direct_delivery']:
            # (lock-step: each message would call the next node's step inside the last one's,
            # the whole run deep; a clock thread would run the nodes beside the executor)
            wired = direct_delivery(container.shells.values())
            # no loop message over DDS: the bridge's loop sleeps to its ticks (spin_clocked)
            container.bridge.quiet = lambda: not any(local.external for local in wired)
            container.log.info('direct delivery between the nodes: '
                               f'{", ".join(local.topic_name for local in wired)}')
        if opts.tee_fd >= 0:
            container.tee = tee_publishers(container.shells.values(), opts.tee_fd,
                                           container.numerical.sub.n_steps)
        if prepare is not None:
            prepare(container)
        code = container.run()
    except ValueError as err:
        print(f'container: error: {err}', file=sys.stderr)
        code = EXIT_BAD_PARAMS
    finally:
        if container is not None:
            container.bridge.bridge.close()
        if rclpy.ok():
            rclpy.shutdown()
    lifeline.end_if_lost(code)
    return code


if __name__ == '__main__':
    sys.exit(main())
