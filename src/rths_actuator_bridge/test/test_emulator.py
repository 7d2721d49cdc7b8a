"""The controller emulator as the reference controller: sequence, limits, channels, clock.

The datagrams are fed to :meth:`ControllerEmulator.handle` directly (no network, no thread),
with the time given, so every case is deterministic.
"""

from conftest import PLANT
import numpy as np
import pytest

from rths_actuator_bridge import protocol as p
from rths_actuator_bridge.emulator import ControllerEmulator
from rths_actuator_bridge.simulated import SimulatedPlant

PEER = ('127.0.0.1', 40000)


def _emulator(**kwargs):
    emu = ControllerEmulator(PLANT, **kwargs)
    sent = []

    class Sock:
        def sendto(self, data, addr):
            sent.append(p.unpack(data))

        def close(self):
            pass

    emu.sock.close()
    emu.sock = Sock()
    return emu, sent


def _command(step, u, version=2, session=0, n=1):
    return p.pack(p.COMMAND, step, np.atleast_1d(u), n, version=version, session=session)


def test_sequence_lost_duplicate_and_late_commands():
    emu, sent = _emulator()
    emu.handle(p.pack(p.ACTIVATE, 0), PEER)
    emu.handle(_command(0, 0.001, 1), PEER)
    emu.handle(_command(3, 0.001, 1), PEER)     # 1, 2 lost: held (ZOH)
    emu.handle(_command(3, 0.001, 1), PEER)     # duplicate: same reply again
    emu.handle(_command(2, 0.001, 1), PEER)     # late: ignored
    assert emu.stats['lost'] == 2 and emu.stats['duplicate'] == 1 and emu.stats['late'] == 1
    replies = [s for s in sent if s.kind == p.REPLY]
    assert [r.step for r in replies] == [0, 3, 3]
    np.testing.assert_array_equal(replies[1].values, replies[2].values)
    assert emu.plants[0].k == 3       # four samples advanced: steps 0..3 (k: the latest)


def test_activate_keeps_the_actuator_where_it_is_and_acks_version_2_with_names():
    emu, sent = _emulator()
    emu.handle(p.pack(p.ACTIVATE, 0, [1024.0], version=2), PEER)
    ack = sent[-1]
    assert ack.kind == p.ACK and ack.version == 2 and ack.active and ack.n_channels == 1
    assert ack.text == 'displacement,force,rel_disp,rel_vel,table_accel'
    session = ack.session
    for k in range(50):
        emu.handle(_command(k, 0.001, session=session), PEER)
    before = emu.plants[0].true['table_disp']
    emu.handle(p.pack(p.ACTIVATE, 0, [1024.0], version=2), PEER)     # a second run
    assert sent[-1].values[0] == pytest.approx(before, abs=1e-4) and abs(before) > 5e-4
    assert emu.plants[0].k == 49 and emu.expected == 0


def test_commands_beyond_its_own_limits_are_not_applied():
    emu, sent = _emulator(stroke_m=0.1)
    emu.handle(p.pack(p.ACTIVATE, 0, [1024.0], version=2), PEER)
    s = sent[-1].session
    emu.handle(_command(0, 0.001, session=s), PEER)
    emu.handle(_command(1, 5.0, session=s), PEER)             # 5 m: beyond the 0.1 m stroke
    r = sent[-1]
    assert r.status & p.ST_LIMITED and r.fault == p.F_LIMIT and 'beyond the stroke' in r.text
    assert emu.held[0] == 0.001 and emu.stats['limited'] == 1
    emu.handle(_command(2, 0.0015, session=s), PEER)
    assert sent[-1].fault == p.F_NONE and emu.held[0] == 0.0015


def test_channel_count_rate_and_session_are_checked():
    emu, sent = _emulator(n_channels=2)
    emu.handle(p.pack(p.ACTIVATE, 0, [1024.0], 1, version=2), PEER)
    assert sent[-1].fault == p.F_CHANNELS and not sent[-1].active and sent[-1].n_channels == 2
    emu.handle(p.pack(p.ACTIVATE, 0, [2048.0], 2, version=2), PEER)
    assert sent[-1].fault == p.F_RATE and '2048 Hz' in sent[-1].text
    emu.handle(p.pack(p.ACTIVATE, 0, [1024.0], 2, version=2), PEER)
    assert sent[-1].active
    emu.handle(_command(0, [0.001, 0.002], session=12345, n=2), PEER)   # not its session
    assert sent[-1].fault == p.F_NOT_ACTIVE and not sent[-1].active


def test_two_channels_are_two_actuators_named_by_channel():
    emu, sent = _emulator(n_channels=2)
    emu.handle(p.pack(p.ACTIVATE, 0, [], 2, version=2), PEER)
    index = p.parse_names(sent[-1].text, 2)
    s = sent[-1].session
    plant = SimulatedPlant(**PLANT)
    for k in range(30):
        emu.handle(_command(k, [0.001, -0.0005], session=s, n=2), PEER)
        plant.step(0.001)
    r = sent[-1].values
    assert r[index[('displacement', 0)]] == pytest.approx(plant.true['table_disp'], abs=1e-4)
    assert r[index[('displacement', 1)]] < 0 < r[index[('displacement', 0)]]


def test_wall_clock_the_actuator_moves_on_while_the_bridge_is_late_and_interlocks():
    emu, sent = _emulator(wall_clock=True, interlock_s=0.1)
    emu.handle(p.pack(p.ACTIVATE, 0, [1024.0], version=2), PEER, now=10.0)
    s = sent[-1].session
    emu.handle(_command(0, 0.001, session=s), PEER, now=10.0)
    emu.handle(_command(1, 0.001, session=s), PEER, now=10.05)     # 50 ms late
    assert emu.samples == 52        # samples 0..50 passed on its clock (held), then step 1's
    emu.handle(_command(2, 0.001, session=s), PEER, now=10.5)      # 450 ms silence: interlock
    r = sent[-1]
    assert not r.active and r.status & p.ST_HOLDING and r.fault == p.F_INTERLOCK
    assert emu.stats['interlocks'] == 1 and abs(emu.held[0]) < 0.001     # ramping to rest


@pytest.mark.parametrize('faults, check', [
    ({'drop_every': 4}, lambda steps, bad: steps == [0, 1, 2, 3, 5, 6, 7, 9] and not bad),
    ({'malformed_at': 2}, lambda steps, bad: 2 not in steps and bad == 1),
    ({'silence_at': 3, 'silence_s': 1.0}, lambda steps, bad: steps == [0, 1, 2]),
    ({'restart_at': 3, 'restart_s': 0.5}, lambda steps, bad: steps == [0, 1, 2]),
])
def test_fault_flags(faults, check):
    emu, _ = _emulator(faults=faults)
    sent = []

    class Sock:
        def sendto(self, data, addr):
            sent.append(data)

    emu.sock = Sock()
    emu.handle(p.pack(p.ACTIVATE, 0, [1024.0], version=2), PEER, now=0.0)
    s = p.unpack(sent[-1]).session
    for k in range(10):
        emu.handle(_command(k, 0.0, session=s), PEER, now=0.001 * k)
    good, bad = [], 0
    for data in sent[1:]:
        try:
            d = p.unpack(data)
        except ValueError:
            bad += 1
            continue
        if d.kind == p.REPLY and d.active:
            good.append(d.step)
    assert check(good, bad), (good, bad)
    if 'restart_at' in faults:     # back after 0.5 s: a new session, inactive
        emu.handle(_command(11, 0.0, session=s), PEER, now=1.0)
        d = p.unpack(sent[-1])
        assert d.session != s and not d.active and d.fault == p.F_NOT_ACTIVE
