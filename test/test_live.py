"""Live view (issue 17): ``rths replay|launch ... --live --port P`` serves the run to Foxglove.

A WebSocket client (the ``websockets`` library, as Foxglove's app connects)
must see the loop topics and the ``/rths/live`` status channel advertised,
receive messages after it subscribes, and see the server close when the
replay (or the run) ends.  The replayed bag is written here: 4 s of a 1024 Hz
loop.  ``rths launch --live`` runs the graph for 2 s in lock-step: the bag
still starts at step 0 (the loop arms only after the live view subscribed).
"""

import asyncio
import json
import socket
import struct
import subprocess

import numpy as np
import pytest

from rths_system_tests import REPO, graph_env, rths_executable

FS = 1024.0
SECONDS = 4.0
#: The issue's target: a client that offers the protocol's older name only (older Foxglove,
#: Lichtblick before foxglove.sdk.v1 support); the SDK server alone answers it with HTTP 400.
LEGACY = ['foxglove.websocket.v1']


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


#: Per actuator: its target's scale and its measured stroke's offset from the target [m].
ACTUATORS = ((1.0, 1e-4), (-2.0, 3e-4))


def _write_bag(bag, n_actuators=1):
    from rths_common import bagio, cdr, topics

    t0 = 1_700_000_000_000_000_000
    acts = ACTUATORS[:n_actuators]
    with bagio.BagWriter(bag, run_info={'fs_hz': FS, 'kind': 'rths'}) as w:
        for k in range(int(SECONDS * FS)):
            t = t0 + int(k * 1e9 / FS)
            target = [g * 0.01 * np.sin(2 * np.pi * 1.0 * k / FS) for g, _ in acts]
            measured = [x - off for x, (_, off) in zip(target, acts, strict=True)]
            w.write(topics.INTERFACE_DISPLACEMENT, t, cdr.pack_step_arrays(t, k, target))
            w.write(topics.MEASUREMENT, t + 1000, cdr.pack_step_arrays(
                t + 1000, k, target, measured, [100.0 * x for x in target]))
            w.write(topics.STATUS, t + 2000, cdr.pack_status(t + 2000, 'bridge', k,
                                                             misses=k // 1000))


async def _client(port, topic='/rths/measurement'):
    import websockets

    uri = f'ws://127.0.0.1:{port}'
    async with websockets.connect(uri, subprotocols=['foxglove.sdk.v1']) as ws:  # today's name
        assert json.loads(await asyncio.wait_for(ws.recv(), 10))['op'] == 'serverInfo'
    async with websockets.connect(uri, subprotocols=LEGACY, max_size=None) as ws:
        channels = {}
        while not {'/rths/live', topic} <= set(channels):
            frame = json.loads(await asyncio.wait_for(ws.recv(), 10))
            if frame.get('op') == 'advertise':
                channels.update({c['topic']: c for c in frame['channels']})
        wanted = {1: channels['/rths/live'], 2: channels[topic]}
        await ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [
            {'id': sid, 'channelId': c['id']} for sid, c in wanted.items()]}))
        received = {1: [], 2: []}
        closed = False
        try:
            while True:
                frame = await asyncio.wait_for(ws.recv(), 20)
                if isinstance(frame, bytes) and frame[0] == 0x01:     # messageData
                    sid, = struct.unpack_from('<I', frame, 1)
                    received[sid].append(frame[13:])
        except websockets.ConnectionClosed:
            closed = True
        return channels, received, closed, ws.subprotocol


def _replay_live(bag):
    """``rths replay BAG --live`` seen by :func:`_client`; its results and the output."""
    port = _free_port()
    proc = subprocess.Popen([rths_executable(), 'replay', str(bag), '--live', '--port',
                             str(port)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, env=graph_env())
    try:
        for line in proc.stdout:                      # the server is up before the replay
            if line.startswith('live view: serving'):
                break
        seen = asyncio.run(_client(port))
        out = line + proc.stdout.read()
        assert proc.wait(30) == 0, out
    finally:
        proc.kill()
    return (*seen, out)


def test_replay_live_is_seen_by_a_foxglove_websocket_client(tmp_path):
    bag = tmp_path / 'bag'
    _write_bag(bag)
    channels, received, closed, subprotocol, out = _replay_live(bag)
    assert subprotocol == 'foxglove.websocket.v1'
    assert {'/rths/interface_displacement', '/rths/command', '/rths/measurement',
            '/rths/status', '/rths/live'} <= set(channels)
    assert channels['/rths/measurement']['encoding'] == 'cdr'
    assert channels['/rths/measurement']['schemaName'] == 'rths_msgs/msg/Measurement'
    live = [json.loads(m) for m in received[1]]
    # decimated to the display rate (50 Hz), never every step (1024 Hz)
    assert 20 <= len(received[2]) <= 60 * SECONDS, len(received[2])
    tracked = [m for m in live if 'tracking_error_m' in m]
    assert tracked and all(abs(m['tracking_error_m'] - 1e-4) < 1e-9 for m in tracked)
    assert max(m['deadline_misses'] for m in live) >= 3      # the bridge's count, 4 s of steps
    assert closed and live[-1]['run_state'] == 'stopped'     # the server stops with the replay
    assert 'live view: stopped' in out


def test_replay_live_of_two_actuators_shows_each(tmp_path):
    """A bag of a two-actuator rig: /rths/live carries both actuators, each paired by step."""
    bag = tmp_path / 'bag'
    _write_bag(bag, n_actuators=2)
    _, received, closed, _, _ = _replay_live(bag)
    live = [json.loads(m) for m in received[1]]
    both = [m for m in live if m.get('n_actuators') == 2]
    assert both and all(len(m['actuators']) == 2 for m in both)
    tracked = [m for m in both if all('tracking_error_m' in a for a in m['actuators'])]
    assert tracked
    for m in tracked:
        for a, (_, offset) in zip(m['actuators'], ACTUATORS, strict=True):
            assert abs(a['tracking_error_m'] - offset) < 1e-9
        assert m['tracking_error_m'] == m['actuators'][0]['tracking_error_m']   # actuator 1's
    assert closed


def test_launch_live_streams_the_run_and_the_bag_still_starts_at_step_0(tmp_path):
    from rths_review.review import read_loop, step_check

    bag, port = tmp_path / 'bag', _free_port()
    proc = subprocess.Popen([rths_executable(), 'launch', '--config', str(REPO / 'config'),
                             '--duration', '2', '--bag', str(bag), '--live', '--port',
                             str(port)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, env=graph_env())
    try:
        for line in proc.stdout:
            if line.startswith('live view: serving'):
                break
        _, received, closed, _ = asyncio.run(_client(port, '/rths/status'))
        out = line + proc.stdout.read()
        assert proc.wait(60) == 0, out[-3000:]
    finally:
        proc.kill()
    live = [json.loads(m) for m in received[1]]
    assert closed and live[-1]['run_state'] == 'stopped' and live[-1]['step'] == 2047
    assert set(live[-1]['misses_by_node']) == {'numerical', 'compensator', 'bridge'}
    assert abs(live[-1]['tracking_error_m']) < 1e-4          # the designed taps track
    assert received[2]                                        # per-node status, decimated
    for topic, data in read_loop(bag)['steps'].items():
        check = step_check(data['step'])
        assert (check['first'], check['last'], check['gaps']) == (0, 2047, 0), (topic, check)


def test_live_view_opened_to_the_network_wants_the_printed_token(tmp_path):
    import websockets

    bag = tmp_path / 'bag'
    _write_bag(bag)
    port = _free_port()
    proc = subprocess.Popen([rths_executable(), 'replay', str(bag), '--live', '--port',
                             str(port), '--host', '0.0.0.0'], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, env=graph_env())

    async def connect(query):
        uri = f'ws://127.0.0.1:{port}/{query}'
        async with websockets.connect(uri, subprotocols=['foxglove.sdk.v1']) as ws:
            return json.loads(await asyncio.wait_for(ws.recv(), 10))['op']
    try:
        for line in proc.stdout:
            if line.startswith('live view: serving'):
                break
        url = line.split()[3]
        assert url.startswith(f'ws://0.0.0.0:{port}/?token='), line
        with pytest.raises(websockets.InvalidStatus, match='401'):
            asyncio.run(connect(''))
        with pytest.raises(websockets.InvalidStatus, match='401'):
            asyncio.run(connect('?token=guess'))
        assert asyncio.run(connect(url[url.index('?'):])) == 'serverInfo'
        assert proc.wait(30) == 0
    finally:
        proc.kill()
