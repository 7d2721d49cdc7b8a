"""The live view's core: display-rate decimation, the run-status record, the shipped layout."""

import json
from pathlib import Path

import pytest

from rths_common import cdr
from rths_live import live


def test_decimator_passes_one_message_per_key_and_period():
    d = live.Decimator(50.0)
    times = [i / 1024.0 for i in range(1024)]                 # one second of a 1024 Hz loop
    assert sum(d.due('a', t) for t in times) == 50
    assert d.due('b', 0.999)                                  # keys are independent
    with pytest.raises(ValueError, match='live-rate'):
        live.Decimator(0.0)


def test_live_record_pairs_target_and_measurement_by_step():
    state = live.LiveState(fs_hz=1024.0, keep_steps=8)
    for k in range(20):
        state.on_target(k, 0.001 * k)
    state.on_status('bridge', 3, 1, 'hold: stroke')
    state.on_status('numerical', 2, 0, '')
    state.on_measurement(15, 0.0149, 42.0)
    rec = state.record()
    assert rec['step'] == 15 and rec['time_s'] == pytest.approx(15 / 1024.0)
    assert rec['tracking_error_m'] == pytest.approx(0.0001)
    assert rec['force_n'] == 42.0 and rec['deadline_misses'] == 5
    assert (rec['safety_state'], rec['fault'], rec['run_state']) == (1, 'hold: stroke', 'running')
    state.on_measurement(3, 0.0, 0.0)                         # its target was dropped (keep 8)
    assert 'tracking_error_m' not in state.record('stopped')
    assert len(state.targets) == 8


def test_live_record_shows_each_actuator_of_a_rig():
    """Two actuators (the messages carry one entry per actuator): each paired by step."""
    state = live.LiveState(fs_hz=1024.0)
    for k in range(10):
        state.on_target(k, (0.001 * k, -0.002 * k))
    state.on_measurement(7, (0.0068, -0.0135), (120.0, -340.0))
    rec = state.record()
    # the top-level fields stay actuator 1's, as for one actuator
    assert rec['target_m'] == pytest.approx(0.007) and rec['measured_m'] == 0.0068
    assert rec['n_actuators'] == 2
    one, two = rec['actuators']
    assert one == {'target_m': pytest.approx(0.007), 'measured_m': 0.0068, 'force_n': 120.0,
                   'tracking_error_m': pytest.approx(0.0002)}
    assert two['target_m'] == pytest.approx(-0.014) and two['force_n'] == -340.0
    assert two['tracking_error_m'] == pytest.approx(-0.0005)
    state.on_measurement(50, (0.0, 0.0), (0.0, 0.0))         # no target of that step (yet)
    assert all(set(a) == {'measured_m', 'force_n'} for a in state.record()['actuators'])
    # one actuator: no per-actuator list (the record as before)
    single = live.LiveState(fs_hz=1024.0)
    single.on_target(3, (0.001,))
    single.on_measurement(3, (0.0009,), (5.0,))
    assert 'actuators' not in single.record() and 'n_actuators' not in single.record()
    assert single.record()['tracking_error_m'] == pytest.approx(0.0001)


def test_shipped_two_actuator_layout_plots_each_actuator():
    shipped = (Path(__file__).resolve().parents[1] / 'foxglove'
               / live.LAYOUT_FILES[2])
    layout = json.loads(shipped.read_text())
    assert layout == live.layout(2)
    text = json.dumps(layout)
    for i in range(2):
        for field in ('target_m', 'measured_m', 'force_n', 'tracking_error_m'):
            assert f'/rths/live.actuators[{i}].{field}' in text
    assert '/rths/live.deadline_misses' in text and '/rths/live.target_m' not in text
    assert 'actuators' in live.LIVE_SCHEMA['properties']


def test_live_record_carries_the_stability_monitor_row():
    state = live.LiveState(fs_hz=1024.0)
    assert 'stability_level' not in state.record()
    state.on_stability([640.0, 4.2, 0.97, 31.0, 0.1, 1.0])   # step delay gain error ti level
    rec = state.record()
    assert (rec['stability_delay_ms'], rec['stability_error_pct'], rec['stability_level']) == \
        (4.2, 31.0, 1)
    assert set(rec) <= set(live.LIVE_SCHEMA['properties'])


def test_status_fields_parse_the_lean_cdr():
    raw = cdr.pack_status(123, 'bridge', 77, missed=True, misses=9, safety_state=2,
                          fault='ramp: watchdog')
    assert live._status_fields(raw) == ('bridge', 9, 2, 'ramp: watchdog')


def test_handshake_rename_only_for_clients_offering_the_old_name_alone():
    req = (b'GET / HTTP/1.1\r\nHost: x\r\nSec-WebSocket-Protocol: foxglove.websocket.v1\r\n'
           b'Sec-WebSocket-Key: abc\r\n\r\n')
    new, changed = live.rewrite_handshake(req, live.LEGACY_SUBPROTOCOL, live.SDK_SUBPROTOCOL)
    assert changed and b'Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n' in new
    assert b'Sec-WebSocket-Key: abc' in new
    both = req.replace(b'foxglove.websocket.v1', b'foxglove.sdk.v1, foxglove.websocket.v1')
    assert live.rewrite_handshake(both, live.LEGACY_SUBPROTOCOL,
                                  live.SDK_SUBPROTOCOL) == (both, False)


def test_shipped_layout_is_the_generated_one_and_plots_the_four_quantities():
    shipped = Path(__file__).resolve().parents[1] / 'foxglove' / 'rths_live.json'
    layout = json.loads(shipped.read_text())
    assert layout == live.layout()      # regenerate: python -c 'from rths_live import live...'
    text = json.dumps(layout)
    for field in ('target_m', 'measured_m', 'force_n', 'tracking_error_m', 'deadline_misses',
                  'stability_delay_ms', 'stability_error_pct', 'stability_level'):
        assert f'/rths/live.{field}' in text
        assert field in live.LIVE_SCHEMA['properties']


REQUEST = (b'GET /?token=s3cret&x=1 HTTP/1.1\r\nHost: h\r\nSec-WebSocket-Protocol: foxglove.sdk.v1'
           b'\r\n\r\n')


def test_the_token_is_checked_in_the_query_or_the_bearer_header_and_never_forwarded():
    head, allowed = live.check_token(REQUEST, 's3cret')
    assert allowed and head.startswith(b'GET /?x=1 HTTP/1.1\r\n') and b's3cret' not in head
    assert not live.check_token(REQUEST, 'other')[1]
    assert not live.check_token(REQUEST.replace(b'?token=s3cret&x=1', b''), 's3cret')[1]
    bearer = REQUEST.replace(b'?token=s3cret&x=1', b'').replace(
        b'Host: h', b'Host: h\r\nAuthorization: Bearer s3cret')
    assert live.check_token(bearer, 's3cret')[1]
    assert live.check_token(bearer, 's3cre')[1] is False        # no prefix match
    assert live.check_token(REQUEST, '')[1]                      # no token: everyone


def test_off_loopback_a_client_always_needs_a_token():
    assert live.access_token('127.0.0.1', {}) == '' and live.access_token('::1', {}) == ''
    assert live.access_token('localhost', {}) == ''
    first, second = live.access_token('0.0.0.0', {}), live.access_token('10.0.0.5', {})
    assert len(first) >= 20 and first != second                 # a new one each start
    assert live.access_token('0.0.0.0', {live.TOKEN_ENV: 'mine'}) == 'mine'
    assert live.access_token('127.0.0.1', {live.TOKEN_ENV: 'mine'}) == 'mine'


def test_tls_files_are_checked_before_anything_starts(tmp_path):
    assert live.tls_context('', '') is None
    with pytest.raises(ValueError, match='--live-tls-key needs --live-tls-cert'):
        live.tls_context('', 'key.pem')
    with pytest.raises(ValueError, match='--live-tls-cert .*missing.pem'):
        live.tls_context(str(tmp_path / 'missing.pem'))
    bad = tmp_path / 'bad.pem'
    bad.write_text('not a certificate')
    with pytest.raises(ValueError, match='PEM certificate'):
        live.tls_context(str(bad))


def _through_bridge(token, request, tls_server=None, tls_client=None):
    """Send ``request`` through a SubprotocolBridge to a stand-in server; return both ends' view."""
    import asyncio
    import socket
    import threading

    seen = []
    upstream = socket.create_server(('127.0.0.1', 0))

    def serve():
        conn, _ = upstream.accept()
        with conn:
            seen.append(conn.recv(4096))
            conn.sendall(b'HTTP/1.1 101 Switching Protocols\r\n\r\n')
    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    bridge = live.SubprotocolBridge('127.0.0.1', 0, upstream.getsockname()[1], token, tls_server)
    try:
        async def client():
            reader, writer = await asyncio.open_connection(
                '127.0.0.1', bridge.port, ssl=tls_client,
                server_hostname='localhost' if tls_client else None)
            writer.write(request)
            answer = await asyncio.wait_for(reader.read(4096), 5)
            writer.close()
            return answer
        answer = asyncio.run(client())
    finally:
        bridge.stop()
        upstream.close()
    thread.join(1)
    return answer, seen


def test_the_bridge_leaves_no_task_behind_when_it_stops(caplog):
    # a connection still relayed at stop() was left pending and logged "Task was destroyed
    # but it is pending!" when collected later; CPython 3.11 formats that log's traceback
    # with ast.parse, which broke a pytest import rewrite in progress (see stop())
    import gc
    import logging
    import socket

    upstream = socket.create_server(('127.0.0.1', 0))
    bridge = live.SubprotocolBridge('127.0.0.1', 0, upstream.getsockname()[1], '')
    client = socket.create_connection(('127.0.0.1', bridge.port))
    client.sendall(REQUEST)
    conn, _ = upstream.accept()               # the relay is open: a task reads each side
    conn.recv(4096)
    conn.sendall(b'HTTP/1.1 101 Switching Protocols\r\n\r\n')
    client.recv(4096)
    with caplog.at_level(logging.ERROR, logger='asyncio'):
        bridge.stop()
        gc.collect()
    for sock in (client, conn, upstream):
        sock.close()
    assert bridge.loop.is_closed() and not bridge.thread.is_alive()
    assert not [r for r in caplog.records if r.name == 'asyncio'], caplog.text


def test_a_client_without_the_token_gets_401_and_never_reaches_the_server():
    answer, seen = _through_bridge('s3cret', REQUEST.replace(b'token=s3cret', b'token=guess'))
    assert answer.startswith(b'HTTP/1.1 401') and b'?token=' in answer and seen == []
    answer, seen = _through_bridge('s3cret', REQUEST)
    assert answer.startswith(b'HTTP/1.1 101') and seen[0].startswith(b'GET /?x=1 ')
    assert b's3cret' not in seen[0]


def test_with_a_certificate_the_live_view_speaks_tls(tmp_path):
    import shutil
    import ssl
    import subprocess
    if shutil.which('openssl') is None:
        pytest.skip('openssl is not installed (it makes the test certificate)')
    subprocess.run(['openssl', 'req', '-x509', '-newkey', 'rsa:2048', '-nodes', '-keyout', 'k.pem',
                    '-out', 'c.pem', '-days', '1', '-subj', '/CN=localhost'],
                   cwd=tmp_path, check=True, capture_output=True)
    server = live.tls_context(str(tmp_path / 'c.pem'), str(tmp_path / 'k.pem'))
    client = ssl.create_default_context(cafile=str(tmp_path / 'c.pem'))
    answer, seen = _through_bridge('s3cret', REQUEST, server, client)
    assert answer.startswith(b'HTTP/1.1 101') and seen[0].startswith(b'GET /?x=1 ')
