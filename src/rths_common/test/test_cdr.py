"""The lean CDR packer/parser of the loop messages agrees with rclpy both ways.

rclpy (Fast-CDR) leaves padding bytes uninitialised and may append trailing
padding after an empty sequence, so the bytes are compared field by field
through both parsers.
"""

import pytest
from rclpy.serialization import deserialize_message, serialize_message

from rths_common import cdr
from rths_msgs.msg import Command, InterfaceDisplacement, LoopStatus, Measurement

STAMP_NS = 1_795_254_003_228_692_887


def stamped(msg, frame_id=''):
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(STAMP_NS, 1_000_000_000)
    msg.header.frame_id = frame_id
    return msg


@pytest.mark.parametrize('values', [[], [0.125], [1.0, -2.5e-3, 3.0]])
def test_one_array_messages_match_rclpy(values):
    for cls, field in ((InterfaceDisplacement, 'displacement'), (Command, 'command')):
        msg = stamped(cls(step=12345, **{field: values}))
        raw = cdr.pack_step_arrays(STAMP_NS, 12345, values)
        ref = serialize_message(msg)
        assert len(raw) <= len(ref)
        back = deserialize_message(raw, cls)
        assert back.step == 12345 and list(getattr(back, field)) == values
        assert back.header == msg.header
        assert cdr.unpack_step_arrays(raw) == (STAMP_NS, 12345, tuple(values))
        assert cdr.unpack_step_arrays(ref) == (STAMP_NS, 12345, tuple(values))


@pytest.mark.parametrize('applied', [[], [0.01], [0.01, 0.02]])
def test_measurement_matches_rclpy(applied):
    n = max(len(applied), 1)
    disp, force = [0.5] * n, [-7.25] * n
    msg = stamped(Measurement(step=7, applied=applied, displacement=disp, force=force))
    raw = cdr.pack_step_arrays(STAMP_NS, 7, applied, disp, force)
    ref = serialize_message(msg)
    assert len(raw) <= len(ref)
    assert deserialize_message(raw, Measurement) == msg
    expected = (STAMP_NS, 7, tuple(applied), tuple(disp), tuple(force))
    assert cdr.unpack_step_arrays(raw, 3) == expected
    assert cdr.unpack_step_arrays(ref, 3) == expected


def test_parser_reads_any_frame_id():
    msg = stamped(Command(step=3, command=[1.5]), frame_id='table')
    assert cdr.unpack_step_arrays(serialize_message(msg)) == (STAMP_NS, 3, (1.5,))
    assert cdr.sender_of(serialize_message(msg)) == 'table'


# frame ids of every length modulo 8 (padding before the step), and a writer gid's text
@pytest.mark.parametrize('frame_id', ['', 'a', 'ab', 'abc', 'abcd', 'abcde', 'abcdef', 'abcdefg',
                                      '01.0f.a3.29.5c.1e.00.00.00.00.00.00.00.00.14.03'])
@pytest.mark.parametrize('values', [[0.125], [1.0, -2.5e-3]])
def test_sender_in_frame_id_matches_rclpy(frame_id, values):
    """The compensator's realtime commands carry its writer gid (the bridge's source check)."""
    msg = stamped(Command(step=77, command=values), frame_id=frame_id)
    raw = cdr.pack_step_arrays(STAMP_NS, 77, values, frame_id=frame_id)
    assert deserialize_message(raw, Command) == msg
    assert cdr.sender_of(raw) == frame_id
    assert cdr.sender_of(serialize_message(msg)) == frame_id
    assert cdr.unpack_step_arrays(raw) == (STAMP_NS, 77, tuple(values))
    meas = cdr.pack_step_arrays(STAMP_NS, 5, [0.1], [0.2], [0.3], frame_id=frame_id)
    assert cdr.unpack_step_arrays(meas, 3) == (STAMP_NS, 5, (0.1,), (0.2,), (0.3,))
    assert deserialize_message(meas, Measurement).header.frame_id == frame_id


@pytest.mark.parametrize('node,fault,missed', [('bridge', '', True),
                                               ('numerical', 'watchdog: no command', False),
                                               ('compensator', 'x' * 13, True)])
def test_status_matches_rclpy(node, fault, missed):
    msg = stamped(LoopStatus(node=node, step=99, step_period_us=976.5, compute_us=12.25,
                             latency_us=-1.0, deadline_missed=missed, deadline_misses=4,
                             safety_state=2, fault=fault))
    raw = cdr.pack_status(STAMP_NS, node, 99, 976.5, 12.25, -1.0, missed, 4, 2, fault)
    assert len(raw) == len(serialize_message(msg))
    assert deserialize_message(raw, LoopStatus) == msg
    assert cdr.status_state(serialize_message(msg)) == (node, 2)


def _status_field_by_field(stamp_ns, node, step, period_us, compute_us, latency_us, missed,
                           misses, safety_state, fault, frame_id):
    """Return the CDR of a LoopStatus written one field at a time (the former packer)."""
    import struct
    buf = bytearray(b'\x00\x01\x00\x00')
    cdr._header(buf, stamp_ns, frame_id)
    cdr._string(buf, node)
    cdr._pad(buf, 8)
    buf += struct.pack('<Q3d?', step, period_us, compute_us, latency_us, missed)
    cdr._pad(buf, 8)
    buf += struct.pack('<QB', misses, safety_state)
    cdr._string(buf, fault)
    return bytes(buf)


@pytest.mark.parametrize('frame_len', range(9))
def test_status_in_one_pack_is_byte_for_byte_the_field_by_field_cdr(frame_len):
    """Every string length modulo 8 (each padding), a run identity and non-ASCII text."""
    for node in ('', 'a', 'bridge', 'numerical', 'compensator', 'site'):
        for fault in ('', 'x', 'xyz', 'watchdog: no command', 'überlast 2 µm'):
            frame = ('vm-1870-c30dcf49|' + 'g' * frame_len)[-frame_len:] if frame_len else ''
            args = (STAMP_NS + frame_len, node, 2**40 + 7, 244.140625, 31.5, -1.0,
                    bool(frame_len % 2), 12, 3, fault, frame)
            raw = cdr.pack_status(*args[:-1], frame_id=frame)
            assert raw == _status_field_by_field(*args)
            msg = deserialize_message(raw, LoopStatus)
            assert (msg.node, msg.fault, msg.header.frame_id, msg.step) == (
                node, fault, frame, 2**40 + 7)
            assert cdr.status_state(raw) == (node, 3)


def test_big_endian_is_refused():
    with pytest.raises(ValueError, match='little-endian'):
        cdr.unpack_step_arrays(b'\x00\x00\x00\x00' + bytes(32))
