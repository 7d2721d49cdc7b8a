"""The run identity in every loop message: a node acts only on its own run's messages."""

import numpy as np
import pytest

from rths_common import cdr
from rths_common.transport import Transport, check_run_id, split_frame
from rths_msgs.msg import Command, LoopStatus


@pytest.mark.parametrize('raw', [False, True])
def test_a_message_of_another_run_is_not_ours(raw):
    mine = Transport(Command, ('command',), raw, 'lab-1-aa')
    other = Transport(Command, ('command',), raw, 'lab-2-bb')
    hand = Transport(Command, ('command',), raw)              # a node started by hand
    msg = mine.encode(7, (np.array([0.01]),), 'gid.01')
    assert mine.ours(msg) and mine.sender(msg) == 'gid.01'
    assert mine.decode(msg)[1:] == (7, ([0.01],) if not raw else ((0.01,),))
    assert not other.ours(msg) and not hand.ours(msg)
    assert not mine.ours(other.encode(7, (np.array([0.2]),), 'gid.01'))
    assert not mine.ours(hand.encode(7, (np.array([0.2]),), 'gid.01'))
    assert hand.ours(hand.encode(7, (np.array([0.2]),), 'gid.01'))
    assert mine.foreign == 2 and mine.foreign_runs == {'lab-2-bb', ''}
    assert mine.foreign_text() == ('2 message(s) of another run (run identity (none), '
                                   'lab-2-bb) ignored')


def test_statuses_carry_the_run_identity():
    typed = Transport(Command, ('command',), False, 'lab-1-aa').status('bridge', 3)
    assert isinstance(typed, LoopStatus) and typed.header.frame_id == 'lab-1-aa|'
    raw = Transport(Command, ('command',), True, 'lab-1-aa').status('bridge', 3)
    assert split_frame(cdr.sender_of(raw)) == ('lab-1-aa', '')


def test_a_run_identity_that_cannot_travel_is_refused():
    assert split_frame('01.0f') == ('', '01.0f')
    with pytest.raises(ValueError, match="without '\\|'"):
        check_run_id('a|b')
