"""UDP protocol: layout, lost/late/duplicate/out-of-order detection, emulator process."""

import time

from conftest import PLANT
import numpy as np
import pytest

from rths_actuator_bridge import udp
from rths_actuator_bridge.bridge import make_backend
from rths_actuator_bridge.emulator import ControllerEmulator


def test_datagram_layout_is_fixed_little_endian():
    data = udp.pack(udp.COMMAND, 5, [0.25], 1)
    assert data[:4] == b'RTHS' and data[4] == 1 and data[5] == udp.COMMAND
    assert len(data) == 18 + 8
    assert int.from_bytes(data[10:18], 'little') == 5
    assert np.frombuffer(data[18:], '<f8')[0] == 0.25
    kind, step, n_ch, values = udp.unpack(data)
    assert (kind, step, n_ch, list(values)) == (udp.COMMAND, 5, 1, [0.25])
    for bad in (data[:10], b'XXXX' + data[4:], data + b'\0'):
        with pytest.raises(ValueError):
            udp.unpack(bad)


def _run(faults, n=40, timeout_s=0.1, pause_s=0.0):
    emu = ControllerEmulator(PLANT, faults=faults).start()
    b = make_backend(dict(PLANT, backend='udp', port=emu.address[1], timeout_s=timeout_s))
    b.activate()
    disp = []
    for k in range(n):
        b.write([0.001 * np.sin(k / 5)])
        disp.append(b.read()[0][0])
        time.sleep(pause_s)
    stats = dict(b.stats)
    b.close()
    emu.stop()
    return np.array(disp), stats, emu.stats


def _reference(n=40):
    from rths_actuator_bridge.simulated import SimulatedPlant
    p = SimulatedPlant(**PLANT)
    out = []
    for k in range(n):
        p.step(0.001 * np.sin(k / 5))
        out.append(p.measure()['table_disp'])
    return np.array(out)


def test_clean_run_counts_nothing():
    disp, stats, emu_stats = _run({})
    assert stats['received'] == 40 and stats['lost'] == stats['late'] == 0
    np.testing.assert_allclose(disp, _reference(), atol=1e-12)


def test_lost_reply_gives_nan_not_a_stale_value():
    disp, stats, _ = _run({'drop': {10, 11}})
    assert stats['lost'] == 2
    assert np.isnan(disp[10]) and np.isnan(disp[11])
    ref = _reference()
    np.testing.assert_allclose(np.delete(disp, [10, 11]), np.delete(ref, [10, 11]), atol=1e-12)


def test_duplicated_reply_is_counted_and_dropped():
    disp, stats, _ = _run({'duplicate': {7, 20}})
    assert stats['duplicate'] == 2 and stats['lost'] == 0
    np.testing.assert_allclose(disp, _reference(), atol=1e-12)


def test_late_reply_is_counted_and_never_used():
    disp, stats, _ = _run({'delay_s': {12: 0.1}}, timeout_s=0.05, pause_s=0.005)
    assert stats['lost'] == 1 and stats['late'] == 1
    assert np.isnan(disp[12])
    ref = _reference()
    np.testing.assert_allclose(np.delete(disp, 12), np.delete(ref, 12), atol=1e-12)


def test_out_of_order_and_malformed_replies():
    disp, stats, _ = _run({'relabel': {15: 16}, 'corrupt': {25}}, timeout_s=0.05)
    assert stats['out_of_order'] == 1 and stats['malformed'] == 1
    assert stats['lost'] == 2 and np.isnan(disp[15]) and np.isnan(disp[25])


def test_emulator_counts_lost_duplicate_and_late_commands():
    emu = ControllerEmulator(PLANT)
    sent = []

    class Sock:
        def sendto(self, data, addr):
            sent.append(udp.unpack(data))

    emu.sock.close()
    emu.sock = Sock()
    emu.handle(udp.pack(udp.ACTIVATE, 0), None)
    emu.handle(udp.pack(udp.COMMAND, 0, [0.001]), None)
    emu.handle(udp.pack(udp.COMMAND, 3, [0.001]), None)     # 1, 2 lost: held (ZOH)
    emu.handle(udp.pack(udp.COMMAND, 3, [0.001]), None)     # duplicate: same reply again
    emu.handle(udp.pack(udp.COMMAND, 2, [0.001]), None)     # late: ignored
    assert emu.stats['lost'] == 2 and emu.stats['duplicate'] == 1
    assert emu.stats['commands'] == 2
    replies = [s for s in sent if s[0] == udp.REPLY]
    assert [r[1] for r in replies] == [0, 3, 3]
    np.testing.assert_array_equal(replies[1][3], replies[2][3])
    assert emu.plant.k == 3       # four samples advanced: steps 0..3


def test_emulator_in_its_own_process(emulator_process):
    """``controller-emulator`` as a separate process; the hardware path end to end."""
    port, stop_emulator = emulator_process
    b = make_backend({'backend': 'udp', 'port': port, 'timeout_s': 2.0})
    b.activate()
    for k in range(200):
        b.write([0.002 * np.sin(k / 20)])
        disp, force = b.read()
    assert np.isfinite(disp[0]) and abs(disp[0]) > 1e-4
    assert b.stats['received'] == 200
    assert 'rel_disp' in b.channels()
    b.close()
    assert stop_emulator()['commands'] == 200
