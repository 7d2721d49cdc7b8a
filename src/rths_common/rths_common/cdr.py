"""Lean (de)serialization of the loop messages: CDR bytes packed and parsed with ``struct``.

In realtime mode the nodes subscribe to the loop topics with ``raw=True`` and
publish bytes: rclpy's generic path (message object -> C struct -> CDR and
back) costs ~20 us to serialize and ~50 us to deserialize a Measurement on
the 2-core VM, several times per step; the fixed layouts below take ~2 us.
The bytes are exactly what rclpy would produce (XCDR1, little endian), so
every ROS tool, the recorder and the bag reader see ordinary messages
(``src/rths_common/test/test_cdr.py`` checks this against rclpy).

Layouts (offsets after the 4-byte encapsulation header, CDR alignment = size):
``InterfaceDisplacement``/``Command``: header, uint64 step, float64[];
``Measurement``: header, uint64 step, 3 x float64[];
``LoopStatus``: header, string node, uint64 step, 3 x float64, bool, uint64,
uint8, string fault.  ``header`` is builtin_interfaces/Time + string frame_id.
"""

import struct

_ENCAP_LE = b'\x00\x01\x00\x00'
_TIME_EMPTY_FRAME = struct.Struct('<iII')   # sec, nanosec, len(frame_id) (1: '' + NUL)
_U32 = struct.Struct('<I')
_U64 = struct.Struct('<Q')


def _pad(buf: bytearray, align: int):
    """Pad ``buf`` so the next field (body offset = len - 4) is aligned to ``align``."""
    rem = (len(buf) - 4) % align
    if rem:
        buf += b'\x00' * (align - rem)


def _header(buf: bytearray, stamp_ns: int):
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    buf += _TIME_EMPTY_FRAME.pack(sec, nanosec, 1)
    buf += b'\x00'


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


def _one_value_layout(n_arrays: int) -> struct.Struct:
    """Whole message ``header (empty frame_id), uint64 step, n_arrays x float64[1]`` as a Struct.

    The one-channel loop messages in one ``pack``/``unpack`` call; field
    offsets as :func:`pack_step_arrays` writes them (encapsulation, sec,
    nanosec, frame_id length 1 + NUL, pad to 8, step, then per array its
    length 1, pad to 8 and the value).
    """
    return struct.Struct('<4siIIx3xQ' + 'I4xd' * n_arrays)


#: Fast layouts of the one-value messages: Command/InterfaceDisplacement (1), Measurement (3).
_ONE_VALUE = {n: _one_value_layout(n) for n in (1, 3)}


def pack_step_arrays(stamp_ns: int, step: int, *arrays) -> bytes:
    """CDR of a message ``header, uint64 step, float64[] x len(arrays)`` (empty frame_id).

    One array: InterfaceDisplacement / Command; three: Measurement
    (applied, displacement, force).
    """
    layout = _ONE_VALUE.get(len(arrays))
    if layout is not None and all(len(values) == 1 for values in arrays):
        sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
        fields = [_ENCAP_LE, sec, nanosec, 1, int(step)]
        for values in arrays:
            fields += (1, values[0])
        return layout.pack(*fields)
    buf = bytearray(_ENCAP_LE)
    _header(buf, stamp_ns)
    _pad(buf, 8)
    buf += _U64.pack(int(step))
    for values in arrays:
        _f64_array(buf, values)
    return bytes(buf)


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


_TIME = struct.Struct('<iI')


def unpack_step_arrays(data: bytes, n_arrays: int = 1) -> tuple:
    """``(stamp_ns, step, array, ...)`` of the CDR of :func:`pack_step_arrays` (any frame_id)."""
    layout = _ONE_VALUE.get(n_arrays)
    if layout is not None and len(data) == layout.size and data[:2] == b'\x00\x01':
        fields = layout.unpack(data)   # one-value arrays and an empty frame_id?
        if fields[3] == 1 and fields[5::2] == (1,) * n_arrays:
            return (fields[1] * 1_000_000_000 + fields[2], fields[4]) + tuple(
                (v,) for v in fields[6::2])
    r = _Reader(data)
    sec, nanosec = r.unpack(_TIME)
    r.string()
    r.align(8)
    (step,) = r.unpack(_U64)
    return (sec * 1_000_000_000 + nanosec, step) + tuple(r.f64_array()
                                                         for _ in range(n_arrays))


_STATUS_NUMBERS = struct.Struct('<Q3d?')
_STATUS_TAIL = struct.Struct('<QB')


def pack_status(stamp_ns: int, node: str, step: int, period_us=0.0, compute_us=0.0,
                latency_us=-1.0, missed=False, misses=0, safety_state=0, fault='') -> bytes:
    """CDR of an ``rths_msgs/LoopStatus`` (field meanings in LoopStatus.msg)."""
    buf = bytearray(_ENCAP_LE)
    _header(buf, stamp_ns)
    _string(buf, node)
    _pad(buf, 8)
    buf += _STATUS_NUMBERS.pack(int(step), float(period_us), float(compute_us),
                                float(latency_us), bool(missed))
    _pad(buf, 8)
    buf += _STATUS_TAIL.pack(int(misses), int(safety_state))
    _string(buf, fault)
    return bytes(buf)
