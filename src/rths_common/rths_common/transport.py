"""The transport adapter of the loop nodes: a loop message <-> ``(stamp, k, arrays)``.

One :class:`Transport` per topic a node reads or writes.  With ``raw`` the
messages are CDR bytes packed and parsed by :mod:`rths_common.cdr` (the lean
path of realtime mode: the subscription is ``raw=True``, the publisher sends
bytes); otherwise typed rths_msgs messages.  Either way the node sees the
same plain values, so each node has one step path.

Run identity.  Every message a loop node sends carries its run's identity
(``run_id``, given to every node of a run by the launcher) in ``header.frame_id``,
``RUN|SENDER`` (``SENDER``: the compensator's writer gid, else empty; without a
run identity just ``SENDER``, as a node started by hand sends).  A node acts only
on messages of its own run (:meth:`Transport.ours`): a message of another run on
the same topics, or of a stray publisher, is counted and dropped.
"""

from rths_common import cdr
from rths_common import node_support as ns
from rths_msgs.msg import LoopStatus

#: Separator of the run identity and the sender in ``header.frame_id``.
RUN_SEP = '|'


def split_frame(frame_id: str) -> tuple:
    """Return ``(run_id, sender)`` of a loop message's ``header.frame_id``."""
    run, sep, sender = frame_id.rpartition(RUN_SEP)
    return (run, sender) if sep else ('', frame_id)


def check_run_id(run_id: str, where: str = 'run_id') -> str:
    """Return ``run_id`` if it can travel in a frame_id (ValueError naming ``where`` if not)."""
    run_id = str(run_id)
    if RUN_SEP in run_id or any(not c.isprintable() for c in run_id) or len(run_id) > 128:
        raise ValueError(f'{where} {run_id!r}: a run identity is up to 128 printable '
                         f"characters without {RUN_SEP!r}; the launcher makes one per run")
    return run_id


class Transport:
    """``msg_type`` with the float64[] ``fields`` (in message order), typed or raw CDR.

    ``run_id``: the identity of the run this node belongs to (:meth:`ours`).
    """

    def __init__(self, msg_type, fields: tuple, raw: bool, run_id: str = ''):
        self.msg_type = msg_type
        self.fields = tuple(fields)
        self.raw = bool(raw)
        self._n = len(self.fields)
        self.run_id = check_run_id(run_id)
        self.foreign = 0           # messages of another run (or none) dropped by ours()
        self.foreign_runs: set[str] = set()  # the other runs' identities seen

    def decode(self, msg) -> tuple:
        """Return ``(stamp_ns, step, arrays)``; each array a sequence of floats."""
        if self.raw:
            values = cdr.unpack_step_arrays(msg, self._n)
            return values[0], values[1], values[2:]
        return (ns.stamp_ns(msg.header), msg.step,
                tuple(list(getattr(msg, name)) for name in self.fields))

    def frame_id(self, msg) -> str:
        """``header.frame_id`` of ``msg`` (typed or CDR)."""
        return cdr.sender_of(msg) if self.raw else msg.header.frame_id

    def sender(self, msg) -> str:
        """Return the sender in ``header.frame_id`` (the compensator's writer gid, '' if none)."""
        return split_frame(self.frame_id(msg))[1]

    def ours(self, msg) -> bool:
        """Return True if ``msg`` belongs to this node's run; else count it and return False."""
        run = split_frame(self.frame_id(msg))[0]
        if run == self.run_id:
            return True
        self.foreign += 1
        self.foreign_runs.add(run)
        return False

    @property
    def status_frame(self) -> str:
        """``header.frame_id`` of this node's other messages (status, specimen): the run."""
        return self._frame()

    def _frame(self, sender: str = '') -> str:
        return f'{self.run_id}{RUN_SEP}{sender}' if self.run_id else sender

    def encode(self, step: int, arrays, frame_id: str = ''):
        """Return the message of ``step`` with ``arrays`` (numpy arrays), stamped now.

        ``frame_id``: the sender (written after the run identity).
        """
        lists = [a.tolist() for a in arrays]
        frame = self._frame(frame_id)
        if self.raw:
            return cdr.pack_step_arrays(ns.now_ns(), step, *lists, frame_id=frame)
        msg = self.msg_type(step=step, **dict(zip(self.fields, lists, strict=True)))
        msg.header.frame_id = frame
        ns.stamp(msg.header, ns.now_ns())
        return msg

    def status(self, node: str, step: int, *, period_us=0.0, compute_us=0.0, latency_us=-1.0,
               missed=False, misses=0, safety_state=LoopStatus.SAFETY_OK, fault=''):
        """Return a LoopStatus of ``node`` for ``step`` in this transport's form, stamped now."""
        frame = self._frame()
        if self.raw:
            return cdr.pack_status(ns.now_ns(), node, step, period_us, compute_us, latency_us,
                                   missed, misses, safety_state, fault, frame_id=frame)
        return ns.status_msg(node, step, period_us=period_us, compute_us=compute_us,
                             latency_us=latency_us, missed=missed, misses=misses,
                             safety_state=safety_state, fault=fault, frame_id=frame)

    def foreign_text(self) -> str:
        """Describe the messages of other runs dropped so far ('' if none)."""
        if not self.foreign:
            return ''
        runs = ', '.join(sorted(r or '(none)' for r in self.foreign_runs))
        return f'{self.foreign} message(s) of another run (run identity {runs}) ignored'
