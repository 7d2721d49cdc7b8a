"""The controller protocol (versions 1 and 2) and the UDP backend against the emulator.

Layouts, malformed datagrams and channel names (protocol.py); the backend's counts of lost,
late, duplicate, out-of-order, malformed and foreign datagrams; the checks at ACTIVATE
(version, channel count, reply names) and the interface it binds to (udp.py).
"""

import socket
import threading
import time

from conftest import PLANT
import numpy as np
import pytest

from rths_actuator_bridge import protocol as p
from rths_actuator_bridge.bridge import make_backend
from rths_actuator_bridge.emulator import ControllerEmulator
from rths_actuator_bridge.simulated import SimulatedPlant


def test_version1_layout_is_fixed_little_endian():
    data = p.pack(p.COMMAND, 5, [0.25], 1)
    assert data[:4] == b'RTHS' and data[4] == 1 and data[5] == p.COMMAND
    assert len(data) == 18 + 8
    assert int.from_bytes(data[10:18], 'little') == 5
    assert np.frombuffer(data[18:], '<f8')[0] == 0.25
    d = p.unpack(data)
    assert (d.kind, d.step, d.n_channels, list(d.values), d.version) == (p.COMMAND, 5, 1, [0.25], 1)
    # the example of docs/controller_protocol.md
    assert data.hex() == '525448530101010001000500000000000000000000000000d03f'


def test_version2_layout_carries_session_sequence_status_fault_and_text():
    data = p.pack(p.ACK, 0, [0.001, -2.5], 1, version=2, session=0xA1B2C3D4, sequence=7,
                  status=p.ST_ACTIVE, text='displacement,force')
    assert len(data) == 30 + 16 + len('displacement,force')
    assert data[4] == 2
    assert int.from_bytes(data[18:22], 'little') == 0xA1B2C3D4
    assert int.from_bytes(data[22:26], 'little') == 7
    assert int.from_bytes(data[26:28], 'little') == p.ST_ACTIVE
    d = p.unpack(data)
    assert (d.session, d.sequence, d.status, d.fault, d.text) == (0xA1B2C3D4, 7, 1, 0,
                                                                  'displacement,force')
    assert d.active and list(d.values) == [0.001, -2.5]


@pytest.mark.parametrize('bad, why', [
    (b'RTHS\x01', 'shorter than the header'),
    (b'XXXX' + p.pack(p.REPLY, 1, [1.0])[4:], 'bad magic'),
    (b'RTHS\x03' + p.pack(p.REPLY, 1, [1.0])[5:], 'unknown version'),
    (p.pack(p.REPLY, 1, [1.0]) + b'\0', 'does not hold'),
    (p.pack(p.REPLY, 1, [1.0])[:-1], 'does not hold'),
    (p.pack(p.REPLY, 1, [1.0])[:5] + bytes([6]) + p.pack(p.REPLY, 1, [1.0])[6:], 'bad kind'),
    (p.pack(p.REPLY, 1, [], version=2)[:29], 'shorter than its 30-byte header'),
    (p.pack(p.REPLY, 1, [], version=2) + b'\xff\xfe', 'not UTF-8'),
])
def test_malformed_datagrams_are_refused_saying_why(bad, why):
    with pytest.raises(ValueError, match=why):
        p.unpack(bad)


def test_reply_names_are_read_by_name_and_checked():
    assert p.parse_names('force,pressure,displacement', 1) == {
        ('force', 0): 0, ('pressure', 0): 1, ('displacement', 0): 2}
    two = p.parse_names('displacement.0,displacement.1,force.0,force.1', 2)
    assert two[('force', 1)] == 3
    with pytest.raises(ValueError, match='force is missing|force are missing'):
        p.parse_names('displacement,pressure', 1)
    with pytest.raises(ValueError, match='needs a channel number'):
        p.parse_names('displacement,force', 2)
    with pytest.raises(ValueError, match='appears twice'):
        p.parse_names('displacement,force,force', 1)
    with pytest.raises(ValueError, match='QUANTITY'):
        p.parse_names('Displacement,force', 1)


def _run(faults, n=40, version=0, timeout_s=0.1, pause_s=0.0):
    emu = ControllerEmulator(PLANT, faults=faults).start()
    b = make_backend(dict(PLANT, backend='udp', port=emu.address[1], timeout_s=timeout_s,
                          protocol_version=version))
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
    plant = SimulatedPlant(**PLANT)
    out = []
    for k in range(n):
        plant.step(0.001 * np.sin(k / 5))
        out.append(plant.measure()['table_disp'])
    return np.array(out)


@pytest.mark.parametrize('version', [1, 2])
def test_clean_run_counts_nothing_in_either_version(version):
    disp, stats, _ = _run({}, version=version)
    assert stats['replies'] == 40
    assert all(stats[k] == 0 for k in stats if k not in ('replies', 'worst_reply_ms'))
    assert 0 < stats['worst_reply_ms'] < 100
    np.testing.assert_allclose(disp, _reference(), atol=1e-12)


def test_lost_reply_gives_nan_not_a_stale_value():
    disp, stats, _ = _run({'drop': {10, 11}})
    assert stats['replies_lost'] == 2
    assert np.isnan(disp[10]) and np.isnan(disp[11])
    ref = _reference()
    np.testing.assert_allclose(np.delete(disp, [10, 11]), np.delete(ref, [10, 11]), atol=1e-12)


def test_duplicated_reply_is_counted_and_dropped():
    disp, stats, _ = _run({'duplicate': {7, 20}})
    assert stats['replies_duplicate'] == 2 and stats['replies_lost'] == 0
    np.testing.assert_allclose(disp, _reference(), atol=1e-12)


def test_late_reply_is_counted_late_not_lost_and_never_used():
    disp, stats, _ = _run({'delay_s': {12: 0.1}}, timeout_s=0.05, pause_s=0.005)
    assert stats['replies_lost'] == 0 and stats['replies_late'] == 1
    assert stats['worst_reply_ms'] >= 100
    assert np.isnan(disp[12])
    ref = _reference()
    np.testing.assert_allclose(np.delete(disp, 12), np.delete(ref, 12), atol=1e-12)


def test_out_of_order_and_malformed_replies():
    disp, stats, _ = _run({'relabel': {15: 16}, 'corrupt': {25}}, timeout_s=0.05)
    assert stats['replies_out_of_order'] == 1 and stats['replies_malformed'] == 1
    assert stats['replies_lost'] == 2 and np.isnan(disp[15]) and np.isnan(disp[25])


def test_replies_from_another_address_are_ignored():
    """A forged REPLY from another socket never reaches the loop; the real one is used."""
    emu = ControllerEmulator(PLANT, faults={'delay_s': {3: 0.05}}).start()
    b = make_backend(dict(PLANT, backend='udp', port=emu.address[1], timeout_s=0.5))
    b.activate()
    forger = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for k in range(5):
            b.write([0.0])
            if k == 3:
                forger.sendto(p.pack(p.REPLY, 3, [9.0, 9.0, 0, 0, 0], version=2,
                                     session=b.session, status=p.ST_ACTIVE), b.local)
            disp, _ = b.read()
            assert abs(disp[0]) < 1e-3
        assert b.stats['datagrams_foreign'] == 1 and b.stats['replies'] == 5
    finally:
        forger.close()
        b.close()
        emu.stop()


def test_the_bridge_binds_the_configured_interface():
    emu = ControllerEmulator(PLANT).start()
    try:
        b = make_backend(dict(PLANT, backend='udp', port=emu.address[1]))
        assert b.local[0] == '127.0.0.1'          # the interface routed to the controller
        b.close()
        with pytest.raises(OSError, match='local_host'):   # TEST-NET-3: on no interface here
            make_backend(dict(PLANT, backend='udp', port=emu.address[1],
                              local_host='203.0.113.7'))
    finally:
        emu.stop()


@pytest.mark.parametrize('version', [1, 2])
def test_activate_checks_the_controllers_channel_count(version):
    emu = ControllerEmulator(PLANT, n_channels=1).start()
    try:
        b = make_backend(dict(PLANT, backend='udp', port=emu.address[1], n_channels=2,
                              protocol_version=version))
        with pytest.raises(OSError, match='has 1 channel') as err:
            b.activate()
        assert ('n_channels 2' if version == 1 else '2 channel(s) asked') in str(err.value)
        assert b.lifecycle == 'inactive'
        b.close()
    finally:
        emu.stop()


def test_version_is_negotiated_and_a_version1_controller_still_works():
    """Negotiation: version 2 with the emulator; a controller that knows only version 1 gets it."""
    emu = ControllerEmulator(PLANT).start()
    b = make_backend(dict(PLANT, backend='udp', port=emu.address[1]))
    b.activate()
    assert b.version == 2 and b.names[:2] == ['displacement', 'force']
    b.close()
    emu.stop()

    v1 = _Version1Controller(values=lambda u: [u, 10 * u, 42.0])  # + a pressure, unnamed
    try:
        b = make_backend({'backend': 'udp', 'port': v1.port, 'timeout_s': 0.2})
        b.activate()
        assert b.version == 1 and v1.refused_v2 >= 1
        b.write([0.002])
        disp, force = b.read()
        assert (disp[0], force[0]) == (0.002, 0.02) and b.channels() == {}   # 42 not rel_disp
        b.close()
    finally:
        v1.stop()


def test_version1_extra_values_are_read_by_the_names_given():
    v1 = _Version1Controller(values=lambda u: [42.0, u, 10 * u])
    try:
        b = make_backend({'backend': 'udp', 'port': v1.port, 'protocol_version': 1,
                          'reply_names': 'pressure,displacement,force'})
        b.activate()
        b.write([0.003])
        disp, force = b.read()
        assert (disp[0], force[0]) == (0.003, 0.03)
        b.close()
    finally:
        v1.stop()


def test_a_controller_restart_is_detected_by_its_new_session():
    emu = ControllerEmulator(PLANT, faults={'restart_at': 5, 'restart_s': 0.05}).start()
    b = make_backend(dict(PLANT, backend='udp', port=emu.address[1], timeout_s=0.02))
    b.activate()
    try:
        for _ in range(12):
            b.write([0.0])
            b.read()
            time.sleep(0.01)
        assert b.stats['restarts'] == 1
        assert b.fault.startswith('controller restart: session')
    finally:
        b.close()
        emu.stop()


class _Version1Controller:
    """A minimal version-1 controller: ACK and REPLY as the document's version 1 says."""

    def __init__(self, values):
        self.values = values
        self.refused_v2 = 0
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(('127.0.0.1', 0))
        self.sock.settimeout(0.05)
        self.port = self.sock.getsockname()[1]
        self.running = True
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self):
        import struct
        header = struct.Struct('<4sBBHHQ')
        while self.running:
            try:
                data, addr = self.sock.recvfrom(2048)
            except (socket.timeout, OSError):
                continue
            magic, version, kind, n_ch, n_val, step = header.unpack_from(data)
            if version != 1 or len(data) != 18 + 8 * n_val:
                self.refused_v2 += 1
                continue
            if kind in (3, 4):
                self.sock.sendto(header.pack(b'RTHS', 1, 5, 1, 0, 0), addr)
            elif kind == 1:
                u = struct.unpack_from('<d', data, 18)[0]
                vals = self.values(u)
                self.sock.sendto(header.pack(b'RTHS', 1, 2, 1, len(vals), step)
                                 + struct.pack(f'<{len(vals)}d', *vals), addr)

    def stop(self):
        self.running = False
        self.thread.join(1.0)
        self.sock.close()


def test_every_hex_example_of_the_protocol_document_decodes():
    """docs/controller_protocol.md: each example is a well-formed datagram of its version."""
    import pathlib
    import re

    doc = next(parent / 'docs' / 'controller_protocol.md'
               for parent in pathlib.Path(__file__).resolve().parents
               if (parent / 'docs' / 'controller_protocol.md').is_file())
    blocks = re.findall(r'```hex\n(.*?)```', doc.read_text(), re.S)
    lines = [line for block in blocks for line in block.splitlines() if line.strip()]
    decoded = [p.unpack(bytes.fromhex(line.replace(' ', ''))) for line in lines]
    assert len(decoded) == 13
    assert [d.version for d in decoded] == [1] * 5 + [2] * 8
    assert [d.kind for d in decoded] == [p.ACTIVATE, p.ACK, p.COMMAND, p.REPLY, p.DEACTIVATE,
                                         p.ACTIVATE, p.ACK, p.COMMAND, p.REPLY, p.REPLY,
                                         p.HEARTBEAT, p.DEACTIVATE, p.ACK]
    assert decoded[3].values.tolist() == [0.001, -12.5] and decoded[2].step == 5
    assert decoded[6].text == 'displacement,force' and decoded[6].session == 0x1A2B3C4D
    assert p.fault_text(decoded[9]) == 'command limit: stroke'
