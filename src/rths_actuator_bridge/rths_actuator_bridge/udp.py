"""UDP hardware backend: :class:`UdpBackend` talks to a lab's servo controller.

The datagrams are those of :mod:`.protocol` (reference: ``docs/controller_protocol.md``).
At ACTIVATE the backend negotiates the version (2, else 1, or the one
``protocol_version`` names) and checks the controller's ACK: its channel count
must be the bridge's ``n_channels``; a version-2 ACK must say ACTIVE and name
the REPLY values (``displacement``, ``force`` per channel, extras such as
``rel_disp``), which are then read by name; a version-1 REPLY is read by the
names in ``reply_names`` (default: displacement then force of every channel).

Per step :meth:`UdpBackend.write` sends COMMAND k and :meth:`UdpBackend.read`
waits for REPLY k until its deadline (``timeout_s`` in lock-step, the bridge's
realtime budget otherwise) and never longer.  Only datagrams from the
configured controller address are read (others: ``datagrams_foreign``).  A
step without a usable reply by the deadline reads NaN (never a stale value;
the bridge fills it by its gap policy).  Counts (:attr:`UdpBackend.stats`,
:data:`STAT_KEYS`): ``replies`` used, ``replies_lost`` (steps whose reply never
came, or came malformed), ``replies_late`` (came after the deadline),
``replies_malformed`` (datagrams that could not be used), ``replies_duplicate``,
``replies_out_of_order``, ``datagrams_foreign``, ``restarts`` (version 2: a new
session) and ``worst_reply_ms`` (longest COMMAND -> REPLY time seen).  A
restart, an inactive controller or a fault the controller reports sets
:attr:`UdpBackend.fault`, which the bridge turns into a safe stop.
"""

import socket
import time

import numpy as np

from . import protocol as p
from .backend import Backend

#: UDP-backend parameters: key -> (type, default, meaning with unit).
UDP_PARAMS = {
    'host': (str, '127.0.0.1', 'IPv4 address of the servo controller'),
    'port': (int, 0, 'UDP port of the servo controller (1..65535)'),
    'local_host': (str, '', "IPv4 address of the bridge's interface to the controller "
                   "('' = the interface the system routes to host)"),
    'local_port': (int, 0, 'local UDP port of the bridge (0 = any)'),
    'timeout_s': (float, 0.25, '[s] lock-step: how long the bridge waits for the reply of a step'),
    'reply_budget': (float, 0.5, '[-] realtime: fraction of the sample period the bridge waits '
                     'for the reply after its COMMAND; a later reply is late'),
    'n_channels': (int, 1, '[-] number of actuators'),
    'protocol_version': (int, 0, '[-] 0 = negotiate (2, else 1), or 1 or 2 only'),
    'reply_names': (str, '', "names of the REPLY values, comma separated ('' = version 2: "
                    "the controller's ACK; version 1: displacement and force per channel)"),
}
#: Ranges of the numeric entries of :data:`UDP_PARAMS` (inclusive).
UDP_RANGES = {
    'port': (0, 65535),
    'local_port': (0, 65535),
    'timeout_s': (0.0, 10.0),
    'reply_budget': (0.05, 0.9),
    'n_channels': (1, 64),
    'protocol_version': (0, 2),
}
STAT_KEYS = ('replies', 'replies_lost', 'replies_late', 'replies_malformed', 'replies_duplicate',
             'replies_out_of_order', 'datagrams_foreign', 'restarts', 'worst_reply_ms')
#: Steps of COMMAND send times kept to time late replies.
SENT_HISTORY = 4096
#: Names of the extra REPLY quantities the bridge hands on as specimen channels (channel 0).
SPECIMEN_CHANNELS = ('rel_disp', 'rel_vel', 'table_accel')


def route_to(host: str) -> str:
    """Return the local IPv4 address the system routes to ``host`` (OSError if none)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.connect((host, 9))      # no datagram is sent: this only picks the route
        return probe.getsockname()[0]


def _params(params: dict) -> dict:
    out = {}
    for key, (typ, default, meaning) in UDP_PARAMS.items():
        raw = params.get(key, default)
        try:
            out[key] = typ(raw)
        except (TypeError, ValueError):
            raise ValueError(f'parameter {key!r} = {raw!r} is not a {typ.__name__}: '
                             f'{meaning}') from None
    for key, (lo, hi) in UDP_RANGES.items():
        if not lo <= out[key] <= hi:
            raise ValueError(f'parameter {key!r} = {out[key]} must lie in [{lo}, {hi}]: '
                             f'{UDP_PARAMS[key][2]}')
    if not 1 <= out['port']:
        raise ValueError(f"parameter 'port' = {out['port']} must be the controller's UDP port "
                         '1..65535')
    if not out['timeout_s'] > 0:
        raise ValueError(f"parameter 'timeout_s' = {out['timeout_s']} must be > 0 s")
    for key in ('host', 'local_host'):
        if out[key] or key == 'host':
            try:
                socket.inet_aton(out[key])
            except OSError:
                raise ValueError(f'parameter {key!r} = {out[key]!r} must be an IPv4 address '
                                 '(e.g. 127.0.0.1)') from None
    return out


class UdpBackend(Backend):
    """Backend talking to a servo controller over UDP (see the module docstring)."""

    summary = 'a servo controller over UDP (docs/controller_protocol.md)'
    params = UDP_PARAMS
    ranges = UDP_RANGES

    @classmethod
    def make_safe(cls, params: dict) -> str:
        """Send DEACTIVATE to the servo controller of ``params``; OSError without its ACK.

        From the bridge's own address where it was fixed (``local_host``/``local_port``;
        the bridge is gone).  A version-2 ACK says whether the controller is still ACTIVE.
        """
        host, port = str(params.get('host', '127.0.0.1')), int(params.get('port', 0))
        n_channels = int(params.get('n_channels', 1))
        local = (str(params.get('local_host', '') or ''), int(params.get('local_port', 0) or 0))
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            try:
                sock.bind(local)
            except OSError:
                sock.bind(('', 0))
            sock.settimeout(0.2)
            for _ in range(5):
                sock.sendto(p.pack(p.DEACTIVATE, 0, (), n_channels), (host, port))
                try:
                    data, addr = sock.recvfrom(65536)
                    ack = p.unpack(data)
                except (socket.timeout, ValueError):
                    continue
                if ack.kind != p.ACK or addr != (host, port):
                    continue
                if ack.version == 1:
                    return (f'servo controller {host}:{port} acknowledged DEACTIVATE (a '
                            'version-1 controller does not report its state: its own interlock '
                            'must bring the actuator to rest)')
                state = ('inactive: actuator stopped' if not ack.active
                         else 'STILL ACTIVE: stop the actuator at the controller')
                return f'servo controller {host}:{port} acknowledged DEACTIVATE ({state})'
        raise OSError(f'no ACK from {host}:{port}')

    def _configure(self, params: dict):
        cfg = _params(params)
        if cfg['reply_names']:
            p.parse_names(cfg['reply_names'], cfg['n_channels'])
        self.params = cfg
        self.n_channels = cfg['n_channels']
        self.addr = (cfg['host'], cfg['port'])
        self.address = f'{cfg["host"]}:{cfg["port"]}'
        if getattr(self, 'sock', None) is not None:
            self.sock.close()
            self.sock = None
        local = cfg['local_host'] or route_to(cfg['host'])
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.bind((local, cfg['local_port']))
        except OSError as err:
            sock.close()
            raise OSError(f"cannot bind the bridge's UDP socket to {local}:{cfg['local_port']} "
                          f'({err.strerror}); check local_host/local_port') from None
        self.sock = sock
        self.local = sock.getsockname()
        self.stats = dict.fromkeys(STAT_KEYS, 0)
        self.stats['worst_reply_ms'] = 0.0
        self.revision = 0            # bumped whenever a count or the fault changes
        self.version = 0
        self.session = 0
        self.status = 0
        self.fault = ''
        self.names = []
        self.index = {}
        self._sequence = 0
        self._extra = {}
        self._reset_run()

    def _reset_run(self):
        self._used = set()
        self._missed = set()
        self._sent = {}

    # ---------------------------------------------------------------- datagrams
    def _send(self, kind: int, step: int, values=(), version: int = None):
        version = version or self.version or 1
        self._sequence += 1
        self.sock.sendto(p.pack(kind, step, values, self.n_channels, version=version,
                                session=self.session, sequence=self._sequence), self.addr)

    def _count(self, key: str, by=1):
        self.stats[key] += by
        self.revision += 1

    def _receive(self, deadline: float):
        """Next decodable datagram from the controller before ``deadline`` (monotonic), or None."""
        sock = self.sock
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                sock.setblocking(False)
                try:
                    data, addr = sock.recvfrom(65536)
                except (BlockingIOError, InterruptedError):
                    return None
            else:
                sock.settimeout(left)
                try:
                    data, addr = sock.recvfrom(65536)
                except (socket.timeout, InterruptedError):
                    return None
                except ConnectionRefusedError:   # an ICMP port-unreachable of an earlier send
                    continue
            if addr != self.addr:
                self._count('datagrams_foreign')
                continue
            try:
                d = p.unpack(data)
            except ValueError:
                self._count('replies_malformed')
                continue
            if self.version and d.version != self.version and d.kind == p.REPLY:
                self._count('replies_malformed')     # a version-1 reply in a version-2 session
                continue
            return d

    def _handshake(self, kind: int, version: int, values=()):
        """Send ACTIVATE/DEACTIVATE ``kind`` of ``version``; return the controller's ACK or None."""
        self._send(kind, 0, values, version)
        deadline = time.monotonic() + max(self.params['timeout_s'], 0.2)
        while True:
            d = self._receive(deadline)
            if d is None or d.kind == p.ACK:
                return d

    def _negotiate(self):
        """ACTIVATE with version 2 then 1 (or ``protocol_version`` only); the ACK or OSError."""
        wanted = self.params['protocol_version']
        versions = (2, 1) if wanted == 0 else (wanted,)
        self.version = self.session = 0
        for _ in range(3):
            for version in versions:
                ack = self._handshake(p.ACTIVATE, version,
                                      (self.limits.fs_hz,) if version == 2 else ())
                if ack is not None and (wanted == 0 or ack.version == wanted):
                    return ack
        raise OSError(f'controller at {self.address} does not acknowledge ACTIVATE (protocol '
                      f'version {" or ".join(map(str, versions))}); is it running? check '
                      'host/port and docs/controller_protocol.md')

    def _activate(self):
        ack = self._negotiate()
        where = f'controller at {self.address}'
        if ack.version == 2 and (not ack.active or ack.fault):
            raise OSError(f'{where} refused ACTIVATE: {p.fault_text(ack) or "status not ACTIVE"}')
        if ack.n_channels != self.n_channels:
            self._handshake(p.DEACTIVATE, ack.version)
            raise OSError(f'{where} has {ack.n_channels} channel(s) (its ACK); the bridge is '
                          f'configured with n_channels {self.n_channels}: make them agree')
        given = self.params['reply_names']
        if ack.version == 2:
            try:
                index = p.parse_names(ack.text, self.n_channels)
            except ValueError as err:
                self._handshake(p.DEACTIVATE, 2)
                raise OSError(f'{where}: its ACK names unusable reply channels: {err}') from None
            if given and [n.strip() for n in given.split(',')] != ack.text.split(','):
                self._handshake(p.DEACTIVATE, 2)
                raise OSError(f'{where} names its reply channels {ack.text!r}, but reply_names '
                              f'is {given!r}: leave reply_names empty or make them agree')
            names = ack.text.split(',')
        else:
            names = [n.strip() for n in given.split(',')] if given else p.default_names(
                self.n_channels)
            index = p.parse_names(','.join(names), self.n_channels)
        self.version, self.session, self.status = ack.version, ack.session, ack.status
        self.names, self.index = names, index
        self._disp = [index[('displacement', c)] for c in range(self.n_channels)]
        self._force = [index[('force', c)] for c in range(self.n_channels)]
        self._extras = {q: i for (q, c), i in index.items() if c == 0 and q in SPECIMEN_CHANNELS}
        self.fault = ''
        self._reset_run()

    def _deactivate(self):
        ack = self._handshake(p.DEACTIVATE, self.version or 1)
        if ack is not None and ack.version == 2:
            self.status = ack.status

    def _write(self, command):
        self._sent[self.step] = time.monotonic()
        self._sent.pop(self.step - SENT_HISTORY, None)
        self._send(p.COMMAND, self.step, command)

    # ---------------------------------------------------------------- replies
    def _note_status(self, d, k: int) -> bool:
        """Check a version-2 datagram's session and status; False if the controller restarted."""
        if d.version != 2:
            return True
        self.status = d.status
        if d.session != self.session:
            self._count('restarts')
            self._set_fault(f'controller restart: session {self.session:#010x} -> '
                            f'{d.session:#010x} (seen at step {k})')
            self.session = d.session      # counted once per new session
            return False
        if not d.active:
            self._set_fault(f'controller inactive at step {k}: '
                            f'{p.fault_text(d) or "it no longer takes COMMANDs"}')
            return False
        text = p.fault_text(d)
        if text:
            self._set_fault(f'controller fault at step {d.step}: {text}')
        return True

    def _set_fault(self, text: str):
        if not self.fault:
            self.fault = text
            self.revision += 1

    def _usable(self, d) -> bool:
        n = self.n_channels
        size = d.values.size
        # version 1 may append values nobody named (ignored); version 2 names every value
        named = len(self.names)
        if d.n_channels != n or size < named or (d.version == 2 and size != named):
            return False
        return bool(np.all(np.isfinite(d.values[:len(self.names)])))

    def _read(self, wait_s=None):
        n = self.n_channels
        k = self.step
        deadline = time.monotonic() + (self.params['timeout_s'] if wait_s is None else wait_s)
        while True:
            d = self._receive(deadline)
            now = time.monotonic()
            if d is None:
                self._missed.add(k)
                self.stats['replies_lost'] = len(self._missed)
                self.revision += 1
                self._extra = {}
                return np.full(n, np.nan), np.full(n, np.nan)
            if d.kind not in (p.REPLY, p.HEARTBEAT):
                continue                        # an ACK of an earlier request
            if not self._note_status(d, k) or d.kind == p.HEARTBEAT:
                continue
            if not self._usable(d):
                self._count('replies_malformed')
                continue
            step = d.step
            if step in self._used:
                self._count('replies_duplicate')
                continue
            if step in self._missed:            # after its deadline: late, never used
                self._missed.discard(step)
                self.stats['replies_lost'] = len(self._missed)
                self._count('replies_late')
                self._time_reply(step, now)
                continue
            if step != k:
                self._count('replies_out_of_order')
                continue
            self._used.add(step)
            self._used.discard(step - SENT_HISTORY)
            self.stats['replies'] += 1
            self._time_reply(step, now)
            v = d.values
            self._extra = {q: float(v[i]) for q, i in self._extras.items()}
            return v[self._disp].copy(), v[self._force].copy()

    def _time_reply(self, step: int, now: float):
        sent = self._sent.get(step)
        if sent is not None:
            ms = (now - sent) * 1e3
            if ms > self.stats['worst_reply_ms']:
                self.stats['worst_reply_ms'] = ms
                self.revision += 1

    def reply_wait_s(self, fs_hz: float) -> float:
        """Realtime: how long the bridge waits for a reply after its COMMAND [s]."""
        return self.params['reply_budget'] / fs_hz

    def counts(self) -> dict:
        """Return the controller's counts for reports (:data:`STAT_KEYS`, version, fault, ...)."""
        out = dict(self.stats)
        out['worst_reply_ms'] = round(float(out['worst_reply_ms']), 3)
        out.update(protocol_version=self.version, status=self.status, fault=self.fault,
                   address=self.address)
        return out

    def channels(self) -> dict:
        """Specimen channels of the latest reply, by name (e.g. rel_disp); may be empty."""
        return dict(self._extra)

    def close(self):
        """Deactivate and close the socket."""
        super().close()
        if getattr(self, 'sock', None) is not None:
            self.sock.close()
            self.sock = None
