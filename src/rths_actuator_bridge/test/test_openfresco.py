"""The genericClient / OpenFresco codec on its own: set-up, framing, actions, bad messages."""

import struct

import numpy as np
import pytest

from rths_actuator_bridge import openfresco as of

# What an unmodified OpenSeesPy 3.7.1.2 genericClient of one basic DOF sent to a recording
# server on this machine (element('genericClient', 3, '-node', 3, '-dof', 1, '-server', port)).
OPENSEES_1DOF_SETUP = (1, 1, 1, 0, 1, 0, 0, 0, 1, 0, 256)


def test_generic_client_sizes_are_what_opensees_sends():
    assert of.Sizes.generic_client(1).pack() == struct.pack('<11i', *OPENSEES_1DOF_SETUP)
    sizes = of.Sizes.unpack(struct.pack('<11i', *OPENSEES_1DOF_SETUP))
    assert sizes.n == 1 and sizes.data_size == 256 and sizes.message_bytes == 2048
    # n = 20: the n x n matrix reply needs 400 values, more than the default 256
    assert of.Sizes.generic_client(20).data_size == 400


@pytest.mark.parametrize('values, words', [
    ((1, 1, 1, 0, 1, 0, 0, 0, 1, 0, -5), 'dataSize'),
    ((1, 1, 1, 0, 1, 0, 0, 0, 1, 0, 10 ** 6), 'dataSize'),
    ((0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 256), 'trial displacement'),
    ((2, 2, 2, 0, 1, 0, 0, 0, 2, 0, 3), 'too small'),
    ((2, 1, 2, 0, 1, 0, 0, 0, 2, 0, 256), 'sizeCtrl vel = 1 must be 0 or n = 2'),
    ((-1, 1, 1, 0, 1, 0, 0, 0, 1, 0, 256), '>= 0'),
])
def test_bad_setup_is_refused_naming_the_size(values, words):
    with pytest.raises(of.ProtocolError, match=words):
        of.Sizes.unpack(struct.pack('<11i', *values))


def test_setup_of_wrong_length_is_refused():
    with pytest.raises(of.ProtocolError, match='44'):
        of.Sizes.unpack(b'\x00' * 40)


def test_interface_mismatch_names_both_counts():
    sizes = of.Sizes.generic_client(2)
    sizes.check_interface(2)
    with pytest.raises(of.ProtocolError, match='2 basic DOF.*1 interface DOF.*nothing was moved'):
        sizes.check_interface(1)


def test_trial_round_trip_and_time():
    sizes = of.Sizes.generic_client(2)
    msg = of.encode_request(sizes, of.SET_TRIAL_RESPONSE, [1e-3, -2e-3], [0.1, 0.2], [3.0, 4.0],
                            time=0.25)
    assert len(msg) == sizes.message_bytes
    req = of.decode(msg, sizes)
    assert req.name == 'setTrialResponse'
    np.testing.assert_array_equal(req.disp, [1e-3, -2e-3])
    np.testing.assert_array_equal(req.vel, [0.1, 0.2])
    np.testing.assert_array_equal(req.accel, [3.0, 4.0])
    assert req.time == 0.25 and req.force.size == 0


@pytest.mark.parametrize('head', [42.0, 3.5, float('nan'), 1.0, 2.0])
def test_unknown_action_is_refused(head):
    sizes = of.Sizes.generic_client(1)
    msg = np.zeros(sizes.data_size)
    msg[0] = head
    with pytest.raises(of.ProtocolError, match='unknown action'):
        of.decode(msg.tobytes(), sizes)


@pytest.mark.parametrize('bad', [float('nan'), float('inf'), -float('inf')])
def test_non_finite_trial_is_refused(bad):
    sizes = of.Sizes.generic_client(1)
    msg = of.encode_request(sizes, of.SET_TRIAL_RESPONSE, [bad], [0.0], [0.0], time=0.0)
    with pytest.raises(of.ProtocolError, match='not finite'):
        of.decode(msg, sizes)


def test_non_finite_padding_after_the_used_values_is_ignored():
    sizes = of.Sizes.generic_client(1)
    msg = np.frombuffer(of.encode_request(sizes, of.SET_TRIAL_RESPONSE, [1.0], [0], [0], 0.0),
                        '<f8').copy()
    msg[-1] = np.nan
    assert of.decode(msg.tobytes(), sizes).disp[0] == 1.0


def test_message_of_wrong_size_is_refused():
    sizes = of.Sizes.generic_client(1)
    with pytest.raises(of.ProtocolError, match='dataSize 256'):
        of.decode(b'\x00' * 2040, sizes)


def test_matrix_reply_is_column_ordered_as_opensees_reads_it():
    sizes = of.Sizes.generic_client(2)
    m = np.array([[1.0, 2.0], [3.0, 4.0]])
    values = np.frombuffer(of.encode_matrix(sizes, m), '<f8')
    # OpenSees' Matrix(rData, n, n) is column-major: (0,0), (1,0), (0,1), (1,1)
    np.testing.assert_array_equal(values[:4], [1.0, 3.0, 2.0, 4.0])
    assert values.size == sizes.data_size and not values[4:].any()
    with pytest.raises(ValueError, match='n = 2'):
        of.encode_matrix(sizes, np.eye(3))


def test_daq_reply_holds_the_asked_vectors_in_order():
    sizes = of.Sizes.generic_client(2, daq_disp=True)
    values = of.daq_values(sizes, [1, 2], [9, 9], [9, 9], [30, 40], 7.0)
    np.testing.assert_array_equal(values, [1, 2, 30, 40])
    daq = of.decode_reply(of.encode_reply(sizes, values), sizes)
    np.testing.assert_array_equal(daq['disp'], [1, 2])
    np.testing.assert_array_equal(daq['force'], [30, 40])


def test_framer_cuts_any_chunking_into_the_same_messages():
    sizes = of.Sizes.generic_client(1, data_size=4)
    msgs = [of.encode_request(sizes, a) for a in (of.GET_FORCE, of.COMMIT_STATE, of.DIE)]
    stream = sizes.pack() + b''.join(msgs)
    for chunk in (1, 7, 44, 45, len(stream)):
        framer = of.Framer()
        units = []
        for i in range(0, len(stream), chunk):
            units += framer.feed(stream[i:i + chunk])
        assert units == [sizes, *msgs] and framer.pending == 0 and framer.truncation() == ''


def test_framer_names_a_truncated_message_and_setup():
    sizes = of.Sizes.generic_client(1)
    framer = of.Framer()
    framer.feed(sizes.pack() + b'\x00' * 100)
    assert '100 of the 2048 bytes of a message' in framer.truncation()
    framer = of.Framer()
    framer.feed(b'\x01\x00')
    assert '2 of the 44 bytes of a set-up' in framer.truncation()
