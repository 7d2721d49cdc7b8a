"""The live view's core: display-rate decimation, the run-status record, the shipped layout."""

import json
from pathlib import Path

import pytest

from rths_bringup import live
from rths_common import cdr


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
    assert layout == live.layout()      # regenerate: python -c 'from rths_bringup import live...'
    text = json.dumps(layout)
    for field in ('target_m', 'measured_m', 'force_n', 'tracking_error_m', 'deadline_misses',
                  'stability_delay_ms', 'stability_error_pct', 'stability_level'):
        assert f'/rths/live.{field}' in text
        assert field in live.LIVE_SCHEMA['properties']
