"""Live view: a Foxglove WebSocket server streaming the running loop at a display rate.

``rths run|launch|replay ... --live [--port 8765]`` starts this module as its own
process (``python -m rths_live.live``, niced), so it is never in the step
path: it subscribes to the loop topics like any other reader (best effort,
depth 1), keeps only what the display needs and forwards it to the
``foxglove-sdk`` server on localhost:

The server (subprotocol ``foxglove.sdk.v1``) sits behind :class:`SubprotocolBridge`,
so clients that offer only the protocol's older name ``foxglove.websocket.v1``
connect too.  What it streams:

* the loop topics as their recorded CDR bytes with their ``ros2msg`` schemas
  (``/rths/interface_displacement``, ``/rths/command``, ``/rths/measurement``,
  ``/rths/status`` per node), each decimated to ``--rate`` (default 50 Hz);
* ``/rths/live`` (JSON), the run's status at the same rate: step, target and
  measured displacement, tracking error, force, deadline misses per node, the
  bridge's safety state, the stability monitor's estimates (``/rths/stability``,
  when the compensator runs one: docs/monitor.md) and ``run_state`` (``running``,
  then ``stopped`` when the run ends and the server closes).  The top-level
  target, measured, error and force are actuator 1's; a run of several actuators
  (a bridge ``rig_file``) adds ``n_actuators`` and ``actuators``, one
  ``{target_m, measured_m, tracking_error_m, force_n}`` per actuator in channel
  order.

It listens on 127.0.0.1 unless ``--host`` says otherwise; off loopback a client
must give the access token (``$RTHS_LIVE_TOKEN``, else a new one printed at
start) as ``ws://HOST:PORT/?token=...``, and ``--live-tls-cert`` serves ``wss://``
(:class:`SubprotocolBridge` is the door; docs/lab_network.md).

The layout ``foxglove/rths_live.json`` (installed under
``share/rths_live/foxglove``) plots target vs measured displacement, force,
tracking error and deadline misses; ``foxglove/rths_live_2_actuators.json`` the
same per actuator for a two-actuator rig; :func:`layout` generates both.
"""

import argparse
import asyncio
from collections import deque
import contextlib
import hmac
import ipaddress
import json
import os
from pathlib import Path
import secrets
import signal
import ssl
import subprocess
import sys
import threading
import time
from urllib.parse import parse_qsl, urlencode, urlsplit

from rths_common import bagio, cdr, topics

#: Default WebSocket port of the live view (Foxglove's default).
DEFAULT_PORT = 8765
#: Default display rate [Hz] of every forwarded topic.
DEFAULT_RATE_HZ = 50.0
#: The run-status channel (JSON).
LIVE_TOPIC = '/rths/live'
#: JSON schema of :data:`LIVE_TOPIC` (units in the names: m, N).
LIVE_SCHEMA = {
    'type': 'object',
    'properties': {
        'step': {'type': 'integer'},
        'time_s': {'type': 'number'},
        'target_m': {'type': 'number'},
        'measured_m': {'type': 'number'},
        'tracking_error_m': {'type': 'number'},
        'force_n': {'type': 'number'},
        'deadline_misses': {'type': 'integer'},
        'misses_by_node': {'type': 'object'},
        'safety_state': {'type': 'integer'},
        'fault': {'type': 'string'},
        'stability_delay_ms': {'type': 'number'},
        'stability_error_pct': {'type': 'number'},
        'stability_level': {'type': 'integer'},
        'run_state': {'type': 'string'},
        'n_actuators': {'type': 'integer'},
        'actuators': {'type': 'array', 'items': {'type': 'object', 'properties': {
            'target_m': {'type': 'number'}, 'measured_m': {'type': 'number'},
            'tracking_error_m': {'type': 'number'}, 'force_n': {'type': 'number'}}}},
    },
}
#: The layouts shipped in ``foxglove/``: actuators -> file name.
LAYOUT_FILES = {1: 'rths_live.json', 2: 'rths_live_2_actuators.json'}
READY_LINE = 'live view: serving'
#: Environment variable carrying the access token to the live-view process (never its argv).
TOKEN_ENV = 'RTHS_LIVE_TOKEN'


class Decimator:
    """Let one message per key through every ``1 / rate_hz`` seconds."""

    def __init__(self, rate_hz: float):
        if not rate_hz > 0:
            raise ValueError(f'--live-rate must be > 0 Hz, got {rate_hz}')
        self.period_s = 1.0 / float(rate_hz)
        self._next = {}

    def due(self, key, now_s: float) -> bool:
        """Return True (and restart the key's period) if ``key`` may pass at ``now_s``."""
        due = self._next.get(key)
        if due is not None and now_s < due:
            return False
        # keep the rate exact (no drift by the sample spacing), but never burst after a pause
        late = due is None or now_s - due >= self.period_s
        self._next[key] = (now_s if late else due) + self.period_s
        return True


class LiveState:
    """The run's status from the loop messages: targets by step, misses, safety."""

    def __init__(self, fs_hz: float = 0.0, keep_steps: int = 4096):
        self.fs_hz = float(fs_hz or 0.0)
        self.targets = {}
        self._order = deque()
        self._keep = keep_steps
        self.misses = {}
        self.safety_state = 0
        self.fault = ''
        self.measurement = None
        self.stability = None

    def on_target(self, step: int, value):
        """Remember the interface displacement of ``step`` (a number, or one per actuator)."""
        self.targets[step] = _channels(value)
        self._order.append(step)
        while len(self._order) > self._keep:
            self.targets.pop(self._order.popleft(), None)

    def on_status(self, node: str, misses: int, safety_state: int, fault: str):
        """Take one node's LoopStatus (the bridge's safety state and fault are kept)."""
        self.misses[node] = int(misses)
        if node == 'bridge':
            self.safety_state = int(safety_state)
            self.fault = fault or self.fault

    def on_measurement(self, step: int, displacement, force):
        """Take the newest measurement (numbers, or one per actuator)."""
        self.measurement = (step, _channels(displacement), _channels(force))

    def on_stability(self, row):
        """Take the monitor's row ``[step, delay_ms, gain, error_pct, ti, level]``."""
        if len(row) >= 6:
            self.stability = (float(row[1]), float(row[3]), int(row[5]))

    def record(self, run_state: str = 'running') -> dict:
        """Return the ``/rths/live`` message (fields of :data:`LIVE_SCHEMA`)."""
        out = {'deadline_misses': sum(self.misses.values()), 'misses_by_node': dict(self.misses),
               'safety_state': self.safety_state, 'fault': self.fault, 'run_state': run_state}
        if self.stability is not None:
            out.update(zip(('stability_delay_ms', 'stability_error_pct', 'stability_level'),
                           self.stability, strict=True))
        if self.measurement is not None:
            step, measured, force = self.measurement
            out.update(step=step, measured_m=measured[0], force_n=force[0])
            if self.fs_hz:
                out['time_s'] = step / self.fs_hz
            target = self.targets.get(step)
            if target is not None:
                out.update(target_m=target[0], tracking_error_m=target[0] - measured[0])
            if len(measured) > 1:
                out['n_actuators'] = len(measured)
                out['actuators'] = [
                    {'measured_m': m, **({'force_n': force[i]} if i < len(force) else {}),
                     **({'target_m': target[i], 'tracking_error_m': target[i] - m}
                        if target is not None and i < len(target) else {})}
                    for i, m in enumerate(measured)]
        return out


def _channels(value) -> tuple:
    """Return ``value`` as a tuple of floats: one number, or one per actuator."""
    if isinstance(value, (int, float)):
        return (float(value),)
    return tuple(float(v) for v in value)


#: The subprotocol the foxglove-sdk server speaks, and its older name (same protocol).
SDK_SUBPROTOCOL, LEGACY_SUBPROTOCOL = 'foxglove.sdk.v1', 'foxglove.websocket.v1'


def rewrite_handshake(head: bytes, old: str, new: str) -> tuple:
    """Return ``(head, changed)`` with ``old`` replaced by ``new`` in Sec-WebSocket-Protocol.

    Only when the header offers ``old`` and not ``new`` (a client that offers
    both is left alone).  The accept key depends on Sec-WebSocket-Key only, so
    the handshake stays valid.
    """
    lines = head.split(b'\r\n')
    for i, text in enumerate(lines):
        name, sep, value = text.partition(b':')
        if sep and name.strip().lower() == b'sec-websocket-protocol':
            offered = [v.strip() for v in value.decode('latin-1').split(',')]
            if old in offered and new not in offered:
                offered = [new if v == old else v for v in offered]
                lines[i] = name + b': ' + ', '.join(offered).encode('latin-1')
                return b'\r\n'.join(lines), True
    return head, False


def is_loopback(host: str) -> bool:
    """Return True if ``host`` is reachable from this machine only (127.0.0.0/8, ::1, localhost)."""
    if host.strip().lower() == 'localhost':
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_token(head: bytes, token: str) -> tuple:
    """Return ``(head, allowed)``: is ``token`` in the handshake, and the head without it.

    The client gives the token as the URL's query ``?token=...`` (what a
    Foxglove connection URL carries) or as ``Authorization: Bearer ...``.  The
    comparison takes constant time.  The token is removed from the request line
    before the head goes on to the server.  An empty ``token`` allows everyone.
    """
    lines = head.split(b'\r\n')
    method, _, rest = lines[0].partition(b' ')
    target, _, version = rest.partition(b' ')
    url = urlsplit(target.decode('latin-1'))
    query = parse_qsl(url.query, keep_blank_values=True)
    given = [v for k, v in query if k == 'token']
    for text in lines[1:]:
        name, sep, value = text.partition(b':')
        scheme, _, credential = value.strip().partition(b' ')
        if sep and name.strip().lower() == b'authorization' and scheme.lower() == b'bearer':
            given.append(credential.strip().decode('latin-1'))
    allowed = not token or any(hmac.compare_digest(g.encode(), token.encode()) for g in given)
    rest_query = urlencode([(k, v) for k, v in query if k != 'token'])
    path = (url.path or '/') + (f'?{rest_query}' if rest_query else '')
    lines[0] = b' '.join((method, path.encode('latin-1'), version))
    return b'\r\n'.join(lines), allowed


_REFUSAL = b'rths live view: give the token as ws://HOST:PORT/?token=TOKEN\n'
#: The answer to a handshake without the token.
UNAUTHORIZED = (b'HTTP/1.1 401 Unauthorized\r\nContent-Type: text/plain\r\nConnection: close\r\n'
                + f'Content-Length: {len(_REFUSAL)}\r\n\r\n'.encode() + _REFUSAL)


class SubprotocolBridge:
    """Accept clients that offer only ``foxglove.websocket.v1`` (older Foxglove, Lichtblick).

    The foxglove-sdk server answers HTTP 400 to them although the protocol is
    the same under its new name ``foxglove.sdk.v1``.  This TCP relay listens on
    the user's port, renames the subprotocol in the handshake (request and
    answer) when a client offers only the old name, and copies every other byte
    between the client and the server on its private port.

    It is also the door of the live view: with a ``token`` a client whose
    handshake does not carry it gets HTTP 401 and never reaches the server
    (:func:`check_token`); with ``tls`` (an ``ssl.SSLContext``) clients connect
    with ``wss://``.
    """

    def __init__(self, host: str, port: int, target_port: int, token: str = '', tls=None):
        self.target_port = target_port
        self.token = token
        self.loop = asyncio.new_event_loop()
        started = threading.Event()
        self.error = None

        async def start():
            try:
                self.server = await asyncio.start_server(self._client, host, port, ssl=tls)
            except OSError as err:
                self.error = err
            started.set()

        self.thread = threading.Thread(target=self._run, args=(start,), daemon=True)
        self.thread.start()
        started.wait()
        if self.error is not None:
            raise self.error
        self.port = self.server.sockets[0].getsockname()[1]

    def _run(self, start):
        self.loop.run_until_complete(start())
        self.loop.run_forever()

    async def _client(self, reader, writer):
        try:
            head = await reader.readuntil(b'\r\n\r\n')
            head, allowed = check_token(head, self.token)
            if not allowed:
                writer.write(UNAUTHORIZED)
                await writer.drain()
                return
            head, legacy = rewrite_handshake(head, LEGACY_SUBPROTOCOL, SDK_SUBPROTOCOL)
            up_reader, up_writer = await asyncio.open_connection('127.0.0.1', self.target_port)
            up_writer.write(head)
            answer = await up_reader.readuntil(b'\r\n\r\n')
            if legacy:
                answer, _ = rewrite_handshake(answer, SDK_SUBPROTOCOL, LEGACY_SUBPROTOCOL)
            writer.write(answer)
            await asyncio.gather(self._pipe(reader, up_writer), self._pipe(up_reader, writer))
        except (OSError, asyncio.IncompleteReadError, asyncio.LimitOverrunError,
                ssl.SSLError, asyncio.CancelledError):
            # (cancelled: stop() closes the connection; ended so, not cancelled, as
            # asyncio 3.11 logs an error for a cancelled start_server handler)
            pass
        finally:
            writer.close()

    @staticmethod
    async def _pipe(src, dst):
        try:
            while data := await src.read(65536):
                dst.write(data)
                await dst.drain()
        except OSError:
            pass
        finally:
            dst.close()

    def stop(self):
        """Close the listening socket and every relayed connection, then the event loop.

        The cancelled connections are run to their end before the loop stops: a task
        left pending is finalised later, by the garbage collector of whichever thread
        runs it, and logs "Task was destroyed but it is pending!" with a traceback.
        CPython 3.11 formats that traceback with ``ast.parse``, which is not reentrant: a
        collection inside another ``ast.parse`` (pytest rewriting a module on import)
        made that one fail with "AST constructor recursion depth mismatch" (gh-106905;
        rths_live's tests in two CI runs of 2026-11-28).
        """
        async def close():
            self.server.close()
            tasks = [t for t in asyncio.all_tasks() if t is not asyncio.current_task()]
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
        asyncio.run_coroutine_threadsafe(close(), self.loop).result(5)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(5)
        if not self.thread.is_alive():
            self.loop.close()


def layout(n_actuators: int = 1) -> dict:
    """Return the Foxglove layout of the live view (plots of the ``/rths/live`` channel).

    ``n_actuators`` > 1: target vs measured and force per actuator
    (``actuators[i]``), and every actuator's tracking error in one plot.
    """
    # lazy: optional dependency (foxglove)
    from foxglove import layouts as fl

    def plot(title, *series):
        paths = [fl.PlotSeries(value=f'{LIVE_TOPIC}.{field}', label=label, enabled=True,
                               timestamp_method='receiveTime') for field, label in series]
        return fl.SplitItem(content=fl.PlotPanel(title=title, config=fl.PlotConfig(
            paths=paths, show_legend=True, x_axis_val='timestamp', time_window_mode='sliding',
            following_view_width=20.0)))

    if n_actuators > 1:
        act = [f'actuators[{i}]' for i in range(n_actuators)]
        loop = [plot(f'actuator {i + 1}: target vs measured stroke [m]',
                     (f'{a}.target_m', 'target'), (f'{a}.measured_m', 'measured'))
                for i, a in enumerate(act)]
        loop += [plot('axial force per actuator [N]',
                      *((f'{a}.force_n', f'actuator {i + 1}') for i, a in enumerate(act))),
                 plot('tracking error per actuator (target - measured) [m]',
                      *((f'{a}.tracking_error_m', f'actuator {i + 1}')
                        for i, a in enumerate(act)))]
    else:
        loop = [plot('target vs measured displacement [m]', ('target_m', 'target'),
                     ('measured_m', 'measured')),
                plot('measured force [N]', ('force_n', 'force')),
                plot('tracking error (target - measured) [m]', ('tracking_error_m', 'error'))]
    content = fl.SplitContainer(direction='column', items=loop + [
        plot('deadline misses', ('deadline_misses', 'misses (all nodes)')),
        plot('stability monitor: delay [ms], error [%], level (1 warn, 2 stop)',
             ('stability_delay_ms', 'delay'), ('stability_error_pct', 'error'),
             ('stability_level', 'level')),
    ])
    return json.loads(fl.Layout(content=content).to_json())


def layout_path() -> Path:
    """Return the installed layout file (the source tree's when not installed)."""
    try:
        # lazy: optional: tried here, refused with a clear message when missing
        from ament_index_python.packages import get_package_share_directory
        path = Path(get_package_share_directory('rths_live')) / 'foxglove' / 'rths_live.json'
        if path.is_file():
            return path
    except Exception:  # noqa: BLE001 - not installed: the source tree's copy
        pass
    return Path(__file__).resolve().parents[1] / 'foxglove' / 'rths_live.json'


def _status_fields(data: bytes) -> tuple:
    """Return ``(node, deadline_misses, safety_state, fault)`` of a LoopStatus's CDR."""
    r = cdr._Reader(data)
    r.unpack(cdr._TIME)
    r.string()                                   # header.frame_id
    node = r.string()
    r.align(8)
    r.unpack(cdr._STATUS_NUMBERS)                # step, 3 timings, deadline_missed
    r.align(8)
    misses, state = r.unpack(cdr._STATUS_TAIL)
    return node, misses, state, r.string()


def add_arguments(p, replay: bool = False):
    """Add ``--live``, ``--port``, ``--host``, ``--live-rate`` and the TLS files to a parser."""
    p.add_argument('--live', action='store_true',
                   help='start a Foxglove WebSocket server streaming the loop topics and the '
                        'run status at the display rate (open ws://HOST:PORT in Foxglove with '
                        'the layout share/rths_live/foxglove/rths_live.json; two actuators: '
                        'rths_live_2_actuators.json)')
    p.add_argument('--port', type=int, default=DEFAULT_PORT,
                   help=f'port of the live view (default {DEFAULT_PORT})')
    p.add_argument('--host', default='127.0.0.1',
                   help='address the live view listens on (default 127.0.0.1: this machine '
                        'only; 0.0.0.0 opens it to the network, and then a client must give '
                        f'the access token: ${TOKEN_ENV} if set, else a new one printed at '
                        'start, as ws://HOST:PORT/?token=TOKEN)')
    p.add_argument('--live-rate', type=float, default=DEFAULT_RATE_HZ,
                   help=f'display rate of the live view [Hz] (default {DEFAULT_RATE_HZ:g})')
    p.add_argument('--live-tls-cert', default='', metavar='PEM',
                   help='certificate of the live view (PEM): clients connect with wss://')
    p.add_argument('--live-tls-key', default='', metavar='PEM',
                   help='private key of --live-tls-cert (PEM; omit it if the certificate '
                        'file holds it)')


def access_token(host: str, environ=None) -> str:
    """Return the live view's access token: ``$RTHS_LIVE_TOKEN``, else a new one off loopback.

    On 127.0.0.1 (the default) there is none unless the variable sets one;
    anywhere else a client always needs one.
    """
    given = (os.environ if environ is None else environ).get(TOKEN_ENV, '').strip()
    if given or is_loopback(host):
        return given
    return secrets.token_urlsafe(18)


def tls_context(cert: str, key: str = ''):
    """Return the live view's server SSL context (None without ``cert``), or refuse the files."""
    if not cert:
        if key:
            raise ValueError('--live-tls-key needs --live-tls-cert (the certificate, PEM)')
        return None
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    try:
        ctx.load_cert_chain(cert, key or None)
    except (OSError, ssl.SSLError) as err:
        raise ValueError(f'--live-tls-cert {cert} --live-tls-key {key or "(none)"}: {err}; give '
                         'a PEM certificate and its private key') from None
    return ctx


@contextlib.contextmanager
def session(args, fs_hz: float = 0.0, timeout_s: float = 30.0):
    """Run the live-view process while the body runs (nothing when ``args.live`` is off)."""
    if not getattr(args, 'live', False):
        yield None
        return
    if not 0 < args.port < 65536:
        raise ValueError(f'--port {args.port}: give a TCP port 1-65535')
    Decimator(args.live_rate)   # validates the rate before anything starts
    cert, key = getattr(args, 'live_tls_cert', ''), getattr(args, 'live_tls_key', '')
    tls_context(cert, key)      # and the TLS files
    cmd = [sys.executable, '-m', 'rths_live.live', '--port', str(args.port), '--host',
           args.host, '--rate', str(args.live_rate), '--fs', str(fs_hz or 0.0),
           '--tls-cert', cert, '--tls-key', key]
    # the token goes by environment, not argv (which every user of the machine can list)
    env = dict(os.environ, **{TOKEN_ENV: access_token(args.host)})
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, env=env)
    try:
        _wait_ready(proc, timeout_s)
        yield proc
    finally:
        _stop(proc)


def _wait_ready(proc, timeout_s: float):
    t_end = time.monotonic() + timeout_s
    for line in proc.stdout:
        print(line, end='', flush=True)
        if line.startswith(READY_LINE):
            return
        if time.monotonic() > t_end:
            break
    raise OSError(f'the live view did not start (exit {proc.poll()}); is the port in use? '
                  'choose another with --port')


def _stop(proc):
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    rest = proc.stdout.read() if proc.stdout else ''
    if rest:
        print(rest, end='', flush=True)


class LiveView:
    """The server and the subscriptions of the live-view process."""

    def __init__(self, host: str, port: int, rate_hz: float, fs_hz: float, token: str = '',
                 tls=None):
        # lazy: optional dependency (foxglove)
        import foxglove

        # lazy: start-up cost: rclpy (~0.3 s), which this module needs only here
        import rclpy
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

        # lazy: start-up cost: rclpy (~0.3 s), which this module needs only here
        from rths_common.node_support import message_class

        # the SDK server on a private port; the bridge on the user's also takes the old name
        self.server = foxglove.start_server(name='rths live view', host='127.0.0.1', port=0)
        try:
            self.bridge = SubprotocolBridge(host, port, self.server.port, token, tls)
        except OSError:
            self.server.stop()
            raise
        store = bagio.typestore()
        self.channels = {
            topic: foxglove.Channel(topic, message_encoding='cdr', schema=foxglove.Schema(
                name=msgtype, encoding='ros2msg',
                data=store.generate_msgdef(msgtype, ros_version=2)[0].encode()))
            for topic, msgtype in topics.LOOP_TOPICS.items() if topic != topics.SPECIMEN}
        self.live = foxglove.Channel(LIVE_TOPIC, schema=LIVE_SCHEMA)
        self.decimator = Decimator(rate_hz)
        self.state = LiveState(fs_hz)
        rclpy.init()
        self.node = rclpy.create_node('live_view')
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                         reliability=ReliabilityPolicy.BEST_EFFORT)
        for topic in self.channels:
            self.node.create_subscription(message_class(topics.LOOP_TOPICS[topic]), topic,
                                          self._callback(topic), qos, raw=True)
        self.node.create_timer(1.0 / rate_hz, self._publish_live)

    def _callback(self, topic):
        # lazy: start-up cost: rclpy (~0.3 s), which this module needs only here
        from rclpy.serialization import deserialize_message
        from std_msgs.msg import Float64MultiArray

        channel, due, state = self.channels[topic], self.decimator.due, self.state

        def on_message(raw: bytes):
            key = topic
            if topic == topics.INTERFACE_DISPLACEMENT:
                _, step, disp = cdr.unpack_step_arrays(raw, 1)
                if disp:
                    state.on_target(step, disp)
            elif topic == topics.MEASUREMENT:
                _, step, _, disp, force = cdr.unpack_step_arrays(raw, 3)
                if disp and force:
                    state.on_measurement(step, disp, force)
            elif topic == topics.STATUS:
                node, misses, safety, fault = _status_fields(raw)
                state.on_status(node, misses, safety, fault)
                key = (topic, node)
            elif topic == topics.STABILITY:   # decimated at the source: decoded typed
                state.on_stability(deserialize_message(raw, Float64MultiArray).data)
            if due(key, time.monotonic()):
                channel.log(raw)
        return on_message

    def _publish_live(self, run_state: str = 'running'):
        self.live.log(self.state.record(run_state))

    def spin(self, parent: int):
        """Serve until SIGINT, SIGTERM or the death of process ``parent``; then close the server."""
        # lazy: start-up cost: rclpy (~0.3 s), which this module needs only here
        from rths_common import node_support as ns

        # a SIGKILLed rths process must not leave the server behind
        ns.spin_until_done(self.node, ns.make_executor('events'),   # the cheapest per message
                           is_done=lambda: os.getppid() != parent)
        self._publish_live('stopped')
        time.sleep(0.2)                       # let the last message reach the clients
        self.server.stop()
        self.bridge.stop()
        self.node.destroy_node()


def main(argv=None) -> int:
    """Entry point of the live-view process (``python -m rths_live.live``)."""
    p = argparse.ArgumentParser(prog='rths live view', description=__doc__.split('\n')[0])
    p.add_argument('--host', default='127.0.0.1')
    p.add_argument('--port', type=int, default=DEFAULT_PORT)
    p.add_argument('--rate', type=float, default=DEFAULT_RATE_HZ)
    p.add_argument('--fs', type=float, default=0.0, help='loop rate [Hz] for time_s (0: none)')
    p.add_argument('--nice', type=int, default=10, help='niceness of this process (default 10)')
    p.add_argument('--tls-cert', default='', help='certificate (PEM): wss:// instead of ws://')
    p.add_argument('--tls-key', default='', help='private key of --tls-cert (PEM)')
    parent = os.getppid()          # first: the rths process may die while this one starts
    args = p.parse_args(argv)
    if args.nice:
        os.nice(args.nice)
    token = access_token(args.host)
    try:
        tls = tls_context(args.tls_cert, args.tls_key)
        view = LiveView(args.host, args.port, args.rate, args.fs, token, tls)
    except (OSError, RuntimeError, ValueError) as err:
        print(f'live view: error: {err}', file=sys.stderr, flush=True)
        return 2
    scheme = 'wss' if tls else 'ws'
    query = f'/?token={token}' if token else ''
    print(f'{READY_LINE} {scheme}://{args.host}:{view.bridge.port}{query} (Foxglove: Open '
          f'connection -> Foxglove WebSocket; layout {layout_path()})', flush=True)
    view.spin(parent)
    with contextlib.suppress(OSError):      # the rths process (our stdout) may be gone
        print('live view: stopped', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
