"""The recording tee of the composed layout: what the container publishes, copied to a pipe.

In the composed layout (:mod:`rths_bringup.container`) the recorder does not
subscribe to the loop topics over DDS (best-effort in realtime: it loses
samples when the machine is loaded).  Instead every publisher of the three
nodes is wrapped in a :class:`TeePublisher`: it publishes as before and hands
the message's CDR bytes (realtime messages already are bytes; lock-step ones
are serialized) to a :class:`Tee`.  In the step path that is one deque append;
a writer thread moves the queue into a pipe in batches, and the recorder
process (``recorder`` with ``pipe_fd``) reads the pipe and writes the bag.

Nothing is dropped while the queue holds fewer than ``capacity`` records (the
container sizes it for the whole run); past that, records are counted as
dropped and the run says so.  A full pipe blocks only the writer thread.

Frame of one record on the pipe: ``<B topic index, q receive time [ns], I
length>`` then the CDR bytes; the topic index is the position of the topic in
:data:`rths_common.topics.LOOP_TOPICS`.
"""

from collections import deque
import fcntl
import os
import struct
import threading
import time

from rths_common import topics

FRAME = struct.Struct('<BqI')
TOPICS = tuple(topics.LOOP_TOPICS)
#: Pipe buffer asked for (F_SETPIPE_SZ; Linux caps it at /proc/sys/fs/pipe-max-size).
PIPE_BYTES = 1 << 20
_F_SETPIPE_SZ = 1031
#: Most records joined into one write (keeps the writer thread's GIL sections short).
BATCH = 256


def topic_index(topic: str) -> int:
    """Index of ``topic`` in the frame (ValueError for a topic the bag does not record)."""
    try:
        return TOPICS.index(topic)
    except ValueError:
        raise ValueError(f'topic {topic} is not a recorded loop topic ({", ".join(TOPICS)})'
                         ) from None


def enlarge_pipe(fd: int) -> int:
    """Ask for a :data:`PIPE_BYTES` pipe buffer; return the size granted (0 if refused)."""
    try:
        return fcntl.fcntl(fd, _F_SETPIPE_SZ, PIPE_BYTES)
    except OSError:
        return 0


class Tee:
    """A bounded queue of (topic index, time, CDR bytes) drained into ``fd`` by a thread."""

    def __init__(self, fd: int, capacity: int, period_s: float = 0.01):
        if capacity < 1:
            raise ValueError(f'tee capacity must be >= 1 record, got {capacity}')
        self.fd = fd
        self.capacity = int(capacity)
        self.period_s = period_s
        self.queue: deque = deque()
        self.records = 0        # records handed to put()
        self.dropped = 0        # records refused (queue full) or lost (pipe closed)
        self.peak = 0           # largest queue length seen by the writer
        self.error: OSError | None = None
        self.running = True
        self.wake = threading.Event()
        self.thread = threading.Thread(target=self._drain, name='rths-tee', daemon=True)
        self.thread.start()

    def put(self, index: int, data: bytes):
        """Queue one message (the step path: an append, no system call)."""
        self.records += 1
        if len(self.queue) >= self.capacity:
            self.dropped += 1
            return
        self.queue.append((index, time.time_ns(), data))

    def _drain(self):
        queue, pack = self.queue, FRAME.pack
        while True:
            running = self.running
            if len(queue) > self.peak:
                self.peak = len(queue)
            while queue:
                parts = []
                for _ in range(min(len(queue), BATCH)):
                    index, t_ns, data = queue.popleft()
                    parts.append(pack(index, t_ns, len(data)))
                    parts.append(data)
                if not self._write(b''.join(parts), len(parts) // 2):
                    self.dropped += len(queue)
                    queue.clear()
                    return
            if not running:
                return
            self.wake.wait(self.period_s)

    def _write(self, buf: bytes, n_records: int) -> bool:
        view = memoryview(buf)
        try:
            while view:
                view = view[os.write(self.fd, view):]
        except OSError as err:   # the recorder is gone (EPIPE): nothing more can be recorded
            self.error = err
            self.dropped += n_records
            return False
        return True

    def close(self) -> dict:
        """Write what is queued, close the pipe; return the counts."""
        self.running = False
        self.wake.set()
        self.thread.join(timeout=60.0)
        try:
            os.close(self.fd)
        except OSError:
            pass
        return {'records': self.records, 'dropped': self.dropped, 'peak_queue': self.peak,
                'error': str(self.error) if self.error else ''}


class TeePublisher:
    """A publisher that also hands every message's CDR bytes to a :class:`Tee`."""

    def __init__(self, publisher, tee: Tee):
        self.publisher = publisher
        self.tee = tee
        self.index = topic_index(publisher.topic_name)

    def publish(self, msg):
        """Queue ``msg``'s bytes for the recorder, then publish ``msg`` (a message or CDR bytes).

        In this order the recording keeps cause before effect where publishing calls
        the readers at once (the container's direct delivery): measurement k is in
        the pipe before the step k + 1 it leads to.
        """
        data = msg
        if not isinstance(data, (bytes, bytearray)):
            # lazy: start-up cost: rclpy (~0.3 s), which this module needs only here
            from rclpy.serialization import serialize_message
            data = serialize_message(data)
        self.tee.put(self.index, data)
        self.publisher.publish(msg)

    def __getattr__(self, name):
        return getattr(self.publisher, name)


def read_records(fd: int, chunk: int = 1 << 16):
    """Yield ``(topic, time_ns, cdr bytes)`` from the pipe ``fd`` until end of file."""
    buf = bytearray()
    size = FRAME.size
    while True:
        data = os.read(fd, chunk)
        if not data:
            return
        buf += data
        pos = 0
        while len(buf) - pos >= size:
            index, t_ns, length = FRAME.unpack_from(buf, pos)
            end = pos + size + length
            if end > len(buf):
                break
            yield TOPICS[index], t_ns, bytes(buf[pos + size:end])
            pos = end
        del buf[:pos]
