"""Lean (de)serialization of the loop messages: CDR bytes packed and parsed with ``struct``.

In realtime mode the nodes subscribe to the loop topics with ``raw=True`` and
publish bytes, skipping rclpy's generic path (message object -> C struct ->
CDR and back; the costs of both: docs/nodes.md).  The bytes are exactly what
rclpy would produce (XCDR1, little endian), so every ROS tool, the recorder
and the bag reader see ordinary messages (``src/rths_common/test/test_cdr.py``
checks this against rclpy).

Layouts (offsets after the 4-byte encapsulation header, CDR alignment = size):
``InterfaceDisplacement``/``Command``: header, uint64 step, float64[];
``Measurement``: header, uint64 step, 3 x float64[];
``LoopStatus``: header, string node, uint64 step, 3 x float64, bool, uint64,
uint8, string fault.  ``header`` is builtin_interfaces/Time + string frame_id.
"""

import functools
import struct

_ENCAP_LE = b'\x00\x01\x00\x00'
_TIME = struct.Struct('<iI')                # builtin_interfaces/Time: sec, nanosec
_U32 = struct.Struct('<I')
_U64 = struct.Struct('<Q')


def _pad(buf: bytearray, align: int):
    """Pad ``buf`` so the next field (body offset = len - 4) is aligned to ``align``."""
    rem = (len(buf) - 4) % align
    if rem:
        buf += b'\x00' * (align - rem)


def _header(buf: bytearray, stamp_ns: int, frame_id: str = ''):
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    buf += _TIME.pack(sec, nanosec)
    _string(buf, frame_id)


def _string(buf: bytearray, text: str):
    _pad(buf, 4)
    data = text.encode()
    buf += _U32.pack(len(data) + 1)
    buf += data
    buf += b'\x00'


def _f64_array(buf: bytearray, values):
    _pad(buf, 4)
    n = len(values)
    buf += _U32.pack(n)
    if n:
        _pad(buf, 8)
        buf += struct.pack(f'<{n}d', *values)


@functools.lru_cache(maxsize=64)
def _one_value_layout(n_arrays: int, frame_len: int = 0) -> struct.Struct:
    """Whole message ``header, uint64 step, n_arrays x float64[1]`` as one Struct.

    The one-channel loop messages in one ``pack``/``unpack`` call, for a
    ``frame_id`` of ``frame_len`` bytes; field offsets as :func:`pack_step_arrays`
    writes them (encapsulation, sec, nanosec, frame_id length + 1, its bytes and
    NUL, pad to 8, step, then per array its length 1, pad to 8 and the value).
    """
    pad = -(12 + frame_len + 1) % 8
    return struct.Struct(f'<4siII{frame_len + 1}s{pad}xQ' + 'I4xd' * n_arrays)


def pack_step_arrays(stamp_ns: int, step: int, *arrays, frame_id: str = '') -> bytes:
    """CDR of a message ``header, uint64 step, float64[] x len(arrays)``.

    One array: InterfaceDisplacement / Command; three: Measurement
    (applied, displacement, force).  ``frame_id`` goes into ``header.frame_id``
    (the compensator's commands carry its writer gid there: :func:`sender_of`).
    """
    frame = frame_id.encode()
    if all(len(values) == 1 for values in arrays):
        sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
        fields = [_ENCAP_LE, sec, nanosec, len(frame) + 1, frame, int(step)]
        for values in arrays:
            fields += (1, values[0])
        return _one_value_layout(len(arrays), len(frame)).pack(*fields)
    buf = bytearray(_ENCAP_LE)
    _header(buf, stamp_ns, frame_id)
    _pad(buf, 8)
    buf += _U64.pack(int(step))
    for values in arrays:
        _f64_array(buf, values)
    return bytes(buf)


def sender_of(data: bytes) -> str:
    """``header.frame_id`` of a stamped loop message's CDR (run identity and sender, or '')."""
    (n,) = _U32.unpack_from(data, 12)   # after encapsulation (4), sec and nanosec (8)
    return data[16:16 + n - 1].decode(errors='replace') if n > 1 else ''


class _Reader:
    """Cursor over CDR bytes (offsets after the encapsulation header)."""

    __slots__ = ('data', 'off')

    def __init__(self, data: bytes):
        if data[:2] != b'\x00\x01':
            raise ValueError('only little-endian XCDR1 (the ROS 2 default) is supported')
        self.data = data
        self.off = 4

    def align(self, n: int):
        rem = (self.off - 4) % n
        if rem:
            self.off += n - rem

    def unpack(self, fmt: struct.Struct):
        values = fmt.unpack_from(self.data, self.off)
        self.off += fmt.size
        return values

    def string(self) -> str:
        self.align(4)
        (n,) = self.unpack(_U32)
        text = self.data[self.off:self.off + n - 1].decode()
        self.off += n
        return text

    def f64_array(self) -> tuple:
        self.align(4)
        (n,) = self.unpack(_U32)
        if not n:
            return ()
        self.align(8)
        values = struct.unpack_from(f'<{n}d', self.data, self.off)
        self.off += 8 * n
        return values


def unpack_step_arrays(data: bytes, n_arrays: int = 1) -> tuple:
    """``(stamp_ns, step, array, ...)`` of the CDR of :func:`pack_step_arrays` (any frame_id)."""
    if data[:2] == b'\x00\x01' and len(data) >= 16:
        layout = _one_value_layout(n_arrays, _U32.unpack_from(data, 12)[0] - 1)
        if len(data) == layout.size:
            fields = layout.unpack(data)   # one-value arrays?
            if fields[6::2] == (1,) * n_arrays:
                return (fields[1] * 1_000_000_000 + fields[2], fields[5]) + tuple(
                    (v,) for v in fields[7::2])
    r = _Reader(data)
    sec, nanosec = r.unpack(_TIME)
    r.string()
    r.align(8)
    (step,) = r.unpack(_U64)
    return (sec * 1_000_000_000 + nanosec, step) + tuple(r.f64_array()
                                                         for _ in range(n_arrays))


_STATUS_NUMBERS = struct.Struct('<Q3d?')
_STATUS_TAIL = struct.Struct('<QB')


@functools.lru_cache(maxsize=64)
def _status_layout(frame_len: int, node_len: int, fault_len: int) -> struct.Struct:
    """Whole ``rths_msgs/LoopStatus`` as one Struct, for strings of these byte lengths.

    Field by field: encapsulation, sec, nanosec, frame_id (length + 1, bytes, NUL), pad to 4,
    node, pad to 8, step, period, compute, latency, missed, pad to 8, misses, safety state,
    pad to 4, fault (offsets from the body, after the 4-byte encapsulation, as :func:`_pad`).
    """
    off = 8 + 4 + frame_len + 1                       # stamp, frame_id
    pad_node = -off % 4
    off += pad_node + 4 + node_len + 1
    pad_numbers = -off % 8
    off += pad_numbers + _STATUS_NUMBERS.size
    pad_tail = -off % 8
    off += pad_tail + _STATUS_TAIL.size
    pad_fault = -off % 4
    return struct.Struct(f'<4siII{frame_len + 1}s{pad_node}xI{node_len + 1}s{pad_numbers}x'
                         f'Q3d?{pad_tail}xQB{pad_fault}xI{fault_len + 1}s')


def pack_status(stamp_ns: int, node: str, step: int, period_us=0.0, compute_us=0.0,
                latency_us=-1.0, missed=False, misses=0, safety_state=0, fault='',
                frame_id: str = '') -> bytes:
    """CDR of an ``rths_msgs/LoopStatus`` (field meanings in LoopStatus.msg), in one pack."""
    frame, name, text = frame_id.encode(), node.encode(), fault.encode()
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return _status_layout(len(frame), len(name), len(text)).pack(
        _ENCAP_LE, sec, nanosec, len(frame) + 1, frame, len(name) + 1, name, int(step),
        float(period_us), float(compute_us), float(latency_us), bool(missed), int(misses),
        int(safety_state), len(text) + 1, text)


def status_state(data: bytes) -> tuple:
    """``(node, safety_state)`` of the CDR of an ``rths_msgs/LoopStatus``."""
    r = _Reader(data)
    r.unpack(_TIME)
    r.string()                                  # header.frame_id
    node = r.string()
    r.align(8)
    r.unpack(_STATUS_NUMBERS)
    r.align(8)
    return node, r.unpack(_STATUS_TAIL)[1]
