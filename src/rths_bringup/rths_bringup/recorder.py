"""Recorder node: writes every loop topic of a run to a rosbag2 bag.

``ros2 run rths_bringup recorder --ros-args -p bag:=out/run/bag -p mode:=lockstep``

The bag is MCAP (``-p storage:=sqlite3`` for the older sqlite3 storage).

Subscriptions take the serialized (CDR) bytes (``raw=True``), so recording
costs no deserialization; a writer thread drains a queue into the bag in
batches (every ``batch_s``, default 0.05 s, at most MAX_BATCH_S; the callbacks
only append to the queue) and commits after each batch once COMMIT_PERIOD_S has
passed, so a SIGKILL of the recorder loses at most the last 0.1 s (one batch
plus one commit period).  This node never
sits in the 1 kHz path of the loop.

Provenance: the bag's run information also gets the rths version and git commit,
the host and the text of the params files of ``config_dir`` (from the launcher)
and of the plant files they name (:mod:`rths_common.provenance`).

Run identity (``run_id``, from the launcher): a stamped loop message of another
run (its ``header.frame_id``, :mod:`rths_common.transport`) is not recorded; the
recorder counts them and says so at the end.  A recorder started without one (by
hand, beside ``rths replay``) records every run's messages.

Realtime mode: the recorder must not take the loop's CPU.  Its threads stay
at normal (SCHED_OTHER) scheduling with a positive nice value (``nice``,
default 10 in realtime, 0 in lock-step) and, if ``cpus`` is set (e.g. ``'0'``),
are pinned to those CPUs, so the SCHED_FIFO loop nodes can have the other core.

Composed layout (``pipe_fd`` = N >= 0, given by the launcher): the container
copies every message its nodes publish on the recorded topics into the pipe N
(:mod:`rths_common.tee`); a reader thread feeds them to the same writer
queue, and only the topics nobody in the container publishes (the emergency
stop) are subscribed to over DDS.  Nothing is lost however loaded the machine
is: the pipe and the container's queue buffer what the writer has not taken
yet.  On SIGINT the recorder keeps reading until the pipe ends (the container
has exited) before it closes the bag.

When the launcher dies (:mod:`rths_common.lifeline`) the recorder keeps
recording until the bridge reports STOPPED (its safe stop is over; composed: the
pipe ended), or until the bridge has been silent for BRIDGE_SILENT_S (it had
stopped or died before: no STOPPED will come), at most LOST_TAIL_S; then it
closes the bag and ends at once (no rclpy teardown: nobody waits for it).
"""

from collections import deque
import os
import sys
import threading
import time

import rclpy

from rths_common import bagstore, cdr, lifeline, provenance, topics
from rths_common import node_support as ns
from rths_common.bagio import BagWriter
from rths_common.qos import STATUS_DEPTH, recorder_qos, status_qos
from rths_common.tee import TOPICS as TEED_TOPICS
from rths_common.tee import read_records
from rths_common.transport import split_frame

#: Recorder parameters that are not run information (everything else is kept in the bag).
RECORDER_PARAMS = ('bag', 'nice', 'cpus', 'batch_s', 'storage', 'pipe_fd', 'config_dir')
#: Recorded topics whose messages carry a header (and so the run identity).
STAMPED = (topics.INTERFACE_DISPLACEMENT, topics.COMMAND, topics.MEASUREMENT, topics.STATUS,
           topics.SPECIMEN, topics.CONTROLLER)
#: Shortest time between two commits of the bag [s]; a crash loses at most this
#: plus one batch (MAX_BATCH_S): 0.1 s.
COMMIT_PERIOD_S = 0.05
#: Longest batch of the writer thread [s] (the ``batch_s`` parameter's upper bound).
MAX_BATCH_S = 0.05
#: After the stop request the recorder keeps taking messages at least this long [s], until
#: none came for TAIL_IDLE_S (what DDS delivered but the recorder had not taken yet, on a
#: loaded machine seconds of the loop: the bridge's safe stop among them), at most
#: MAX_TAIL_S (the launcher sends SIGTERM 5 s after SIGINT) ...
TAIL_S = 0.2
TAIL_IDLE_S = 0.1
MAX_TAIL_S = 4.0
#: ... and after its launcher died, until the bridge reports STOPPED (its safe stop is
#: over), at most LOST_TAIL_S [s] (the run's processes are gone within 1 s) ...
LOST_TAIL_S = 0.6
#: ... or until no status of the bridge came for this long [s] (a live bridge reports
#: every tick, ~1 ms, while it holds and ramps: it had stopped or died already).
BRIDGE_SILENT_S = 0.15
_STOPPED = 3                     # rths_msgs/LoopStatus SAFETY_STOPPED


class Recorder:
    """Subscribe to the loop topics and hand the messages to a writer thread."""

    def __init__(self):
        self.node = ns.make_node('recorder')
        params = ns.parameters(self.node)
        bag = params.get('bag', '')
        if not bag:
            raise ValueError("parameter 'bag' (output directory of the bag) is required: "
                             'pass -p bag:=PATH')
        mode = params.get('mode', 'lockstep')
        self.nice = int(params.get('nice', 10 if mode == 'realtime' else 0))
        self.cpus = str(params.get('cpus', '') or '')
        self.batch_s = float(params.get('batch_s', 0.05))
        self.storage = str(params.get('storage', '') or bagstore.DEFAULT_STORAGE)
        if not 0 < self.batch_s <= MAX_BATCH_S:
            raise ValueError(f"parameter 'batch_s' = {self.batch_s} must lie in "
                             f"(0, {MAX_BATCH_S:g}] s "
                             '(the writer drains the queue this often)')
        # Everything else given to the recorder (fs_hz, ...) is run information kept in the bag.
        self.run_info = {k: v for k, v in params.items() if k not in RECORDER_PARAMS}
        # ... with its provenance: rths version and commit, host, the files of ``config_dir``
        self.run_info.update(provenance.collect(params.get('config_dir') or None))
        self.queue = deque()
        self.bridge_stopped = False    # (after the launcher died) the bridge reported STOPPED
        self.bridge_heard = None       # monotonic time of the bridge's last status (DDS)
        self.taken = 0                 # messages taken from DDS (the tail waits until idle)
        self.wake = threading.Event()
        self.running = True
        self.count = 0
        self.run_id = str(params.get('run_id', '') or '')
        self.foreign = 0
        # sqlite objects must stay in the thread that made them: the writer thread opens the bag.
        opened = threading.Event()
        self.open_error = None
        self.thread = threading.Thread(target=self._drain, args=(bag, opened), daemon=True)
        self.thread.start()
        opened.wait()
        if self.open_error is not None:
            raise self.open_error
        self.pipe_fd = int(params.get('pipe_fd', -1))
        self.piped = 0
        self.pipe_thread = None
        teed = ()
        if self.pipe_fd >= 0:
            teed = TEED_TOPICS
            self.pipe_thread = threading.Thread(target=self._read_pipe, daemon=True)
            self.pipe_thread.start()
        for topic, msgtype in topics.LOOP_TOPICS.items():
            if topic in teed and topic != topics.EMERGENCY_STOP:
                continue   # the container's tee brings every one of these
            qos = (status_qos() if topic in (topics.STATUS, topics.SPECIMEN, topics.CONTROLLER,
                                             topics.RUN_INPUTS, topics.RESPONSE)
                   else recorder_qos(mode))
            self.node.create_subscription(ns.message_class(msgtype), topic,
                                          self._callback(topic), qos, raw=True)
        tuning = self.tune()
        self.node.get_logger().info(f'recording {len(topics.LOOP_TOPICS)} topics to {bag}'
                                    f'{f" ({tuning})" if tuning else ""}')

    def tune(self) -> str:
        """Lower the priority (nice) of every thread and pin them to ``cpus``; describe it.

        Linux nice values are per thread; threads created later inherit them
        from their creator.
        """
        parts = []
        tids = [int(t) for t in os.listdir('/proc/self/task')]
        if self.nice:
            try:
                for tid in tids:
                    os.setpriority(os.PRIO_PROCESS, tid, self.nice)
                parts.append(f'nice {self.nice}')
            except OSError as err:
                parts.append(f'nice {self.nice} refused ({err})')
        if self.cpus:
            parts.append(ns.tune_process(0, self.cpus, 'default').replace(', gc default', ''))
        return ', '.join(parts)

    def hurry(self):
        """Back to nice 0 (where allowed): the run is over, what is in flight must reach the bag."""
        for tid in (int(t) for t in os.listdir('/proc/self/task')):
            try:
                os.setpriority(os.PRIO_PROCESS, tid, 0)
            except OSError:
                return

    def _callback(self, topic):
        queue, now_ns = self.queue, ns.now_ns
        # a stamped topic carries the run identity; a recorder without one takes every run's
        run_id = self.run_id if topic in STAMPED else ''

        def ours(raw: bytes) -> bool:
            if run_id and split_frame(cdr.sender_of(raw))[0] != run_id:
                self.foreign += 1      # another run's message: not this run's record
                return False
            return True

        def on_message(raw: bytes):
            # only a deque append (thread-safe): the writer thread drains in batches
            self.taken += 1
            if ours(raw):
                queue.append((topic, now_ns(), raw))

        def on_status(raw: bytes):
            self.taken += 1
            if not ours(raw):
                return
            queue.append((topic, now_ns(), raw))
            if lifeline.lost():
                node, state = cdr.status_state(raw)
                if node == 'bridge':
                    self.bridge_heard = time.monotonic()
                    self.bridge_stopped = self.bridge_stopped or state == _STOPPED
        return on_status if topic == topics.STATUS else on_message

    def collect_tail(self, lost: bool):
        """Take the messages still in flight after the stop request (module constants).

        After a stop request: at least TAIL_S, then until nothing came for
        TAIL_IDLE_S, at most MAX_TAIL_S.  After the launcher died (processes
        layout): until the bridge's STOPPED status arrived or the bridge fell
        silent (BRIDGE_SILENT_S), at most LOST_TAIL_S; composed, the statuses come
        through the pipe.
        """
        start = time.monotonic()
        executor = ns.make_executor('events')
        executor.add_node(self.node)
        wait_stop = lost and self.pipe_fd < 0
        taken, idle_since = self.taken, start
        while True:
            now = time.monotonic()
            if wait_stop:
                if now - start >= LOST_TAIL_S or self.bridge_stopped or now - max(
                        self.bridge_heard or start, start) > BRIDGE_SILENT_S:
                    break
            else:
                idle = now - idle_since >= TAIL_IDLE_S
                if now - start >= MAX_TAIL_S or (now - start >= TAIL_S and idle):
                    break
            executor.spin_once(timeout_sec=0.01)
            if self.taken != taken:
                taken, idle_since = self.taken, time.monotonic()
        executor.remove_node(self.node)
        self.take_the_rest()

    def take_the_rest(self):
        """Take what is still in the readers: the messages no executor event announced.

        The events the run's executor had queued are dropped when it lets the node go
        (``spin_until_done``) and the tail's executor takes over, so each reader stays
        that many messages behind: the last ones, the bridge's STOPPED status among
        them, were never taken.  A supervisor kill in the processes layout (2026-11-28)
        left 1-4 messages a topic; the bags ended at RAMP, 5-8 steps before the stop.
        At most a reader's history (STATUS_DEPTH) each: a publisher that goes on cannot
        keep it here.
        """
        for sub in self.node.subscriptions:
            for _ in range(STATUS_DEPTH):
                with sub.handle:
                    got = sub.handle.take_message(sub.msg_type, sub.raw)
                if got is None:
                    break
                sub.callback(got[0])

    def _read_pipe(self):
        """Composed layout: the container's records, from the pipe until it ends."""
        queue = self.queue
        for record in read_records(self.pipe_fd):
            queue.append(record)
            self.piped += 1
        os.close(self.pipe_fd)

    def wait_for_pipe(self, timeout_s: float = 60.0) -> bool:
        """Composed layout: wait until the pipe ended (the container exited); False on timeout."""
        if self.pipe_thread is None:
            return True
        self.pipe_thread.join(timeout_s)
        return not self.pipe_thread.is_alive()

    def _drain(self, bag, opened):
        try:
            writer = BagWriter(bag, topics.LOOP_TOPICS, run_info=self.run_info,
                               storage=self.storage)
        except (OSError, ValueError) as err:
            self.open_error = err
            return
        finally:
            opened.set()
        with writer:
            last_commit = time.monotonic()
            while self.running or self.queue:
                self.wake.wait(self.batch_s)   # set only by close()
                queue = self.queue
                while queue:
                    writer.write(*queue.popleft())
                now = time.monotonic()
                if now - last_commit >= COMMIT_PERIOD_S or not self.running:
                    writer.commit()
                    last_commit = now
            self.count = writer.count

    def close(self):
        """Write what is queued, close the bag; return the number of messages written."""
        self.running = False
        self.wake.set()
        self.thread.join()
        return self.count


def main(argv=None):
    """Entry point of ``ros2 run rths_bringup recorder``."""
    lifeline.bind()       # its launcher's death: record the safe stop, close
    rclpy.init(args=argv if argv is not None else sys.argv)
    try:
        rec = Recorder()
    except (ValueError, OSError) as err:
        print(f'recorder: error: {err}', file=sys.stderr)
        rclpy.shutdown()
        return 2
    t0 = time.monotonic()
    # The events executor has the least per-message overhead: the recorder takes every
    # message of every node and must keep up with the loop.
    ns.spin_until_done(rec.node, ns.make_executor('events'), lifeline.lost)
    rec.hurry()      # the loop is over (or its launcher died): take the rest at full speed
    rec.collect_tail(lifeline.lost())
    if not rec.wait_for_pipe():
        print('recorder: the container did not close the recording pipe within 60 s; '
              'BAG INCOMPLETE', flush=True)
    count = rec.close()
    piped = f' ({rec.piped} from the container)' if rec.pipe_fd >= 0 else ''
    foreign = f'; {rec.foreign} of another run not recorded' if rec.foreign else ''
    print(f'recorder: {count} messages written{piped} in {time.monotonic() - t0:.1f} s'
          f'{foreign}', flush=True)
    lifeline.end_if_lost(0)     # the bag is closed: no rclpy teardown once the launcher died
    rclpy.shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
