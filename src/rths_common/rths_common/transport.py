"""The transport adapter of the loop nodes: a loop message <-> ``(stamp, k, arrays)``.

One :class:`Transport` per topic a node reads or writes.  With ``raw`` the
messages are CDR bytes packed and parsed by :mod:`rths_common.cdr` (the lean
path of realtime mode: the subscription is ``raw=True``, the publisher sends
bytes); otherwise typed rths_msgs messages.  Either way the node sees the
same plain values, so each node has one step path.
"""

from rths_common import cdr
from rths_common import node_support as ns
from rths_msgs.msg import LoopStatus


class Transport:
    """``msg_type`` with the float64[] ``fields`` (in message order), typed or raw CDR."""

    def __init__(self, msg_type, fields: tuple, raw: bool):
        self.msg_type = msg_type
        self.fields = tuple(fields)
        self.raw = bool(raw)
        self._n = len(self.fields)

    def decode(self, msg) -> tuple:
        """Return ``(stamp_ns, step, arrays)``; each array a sequence of floats."""
        if self.raw:
            values = cdr.unpack_step_arrays(msg, self._n)
            return values[0], values[1], values[2:]
        return (ns.stamp_ns(msg.header), msg.step,
                tuple(list(getattr(msg, name)) for name in self.fields))

    def sender(self, msg) -> str:
        """``header.frame_id``: the sender's writer gid ('' if none)."""
        return cdr.sender_of(msg) if self.raw else msg.header.frame_id

    def encode(self, step: int, arrays, frame_id: str = ''):
        """Return the message of ``step`` with ``arrays`` (numpy arrays), stamped now."""
        lists = [a.tolist() for a in arrays]
        if self.raw:
            return cdr.pack_step_arrays(ns.now_ns(), step, *lists, frame_id=frame_id)
        msg = self.msg_type(step=step, **dict(zip(self.fields, lists, strict=True)))
        msg.header.frame_id = frame_id
        ns.stamp(msg.header, ns.now_ns())
        return msg

    def status(self, node: str, step: int, *, period_us=0.0, compute_us=0.0, latency_us=-1.0,
               missed=False, misses=0, safety_state=LoopStatus.SAFETY_OK, fault=''):
        """Return a LoopStatus of ``node`` for ``step`` in this transport's form, stamped now."""
        if self.raw:
            return cdr.pack_status(ns.now_ns(), node, step, period_us, compute_us, latency_us,
                                   missed, misses, safety_state, fault)
        return ns.status_msg(node, step, period_us=period_us, compute_us=compute_us,
                             latency_us=latency_us, missed=missed, misses=misses,
                             safety_state=safety_state, fault=fault)
