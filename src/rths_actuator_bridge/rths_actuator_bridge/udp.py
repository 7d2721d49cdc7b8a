"""UDP hardware backend: the datagram protocol to a servo controller and :class:`UdpBackend`.

Datagram layout (little-endian, ``struct``; full description in the package README)::

    header  '<4sBBHHQ'  magic b'RTHS', version 1, kind, n_channels, n_values, step
    payload n_values x float64 ('<d')

    kind 1 COMMAND     bridge -> controller  values: command[n_channels]            [m]
    kind 2 REPLY       controller -> bridge  values: displacement[n], force[n], extra...
    kind 3 ACTIVATE    bridge -> controller  no values; resets the controller's step count
    kind 4 DEACTIVATE  bridge -> controller  no values
    kind 5 ACK         controller -> bridge  answer to 3/4, same values as REPLY

``extra`` values of a REPLY (emulator: DTM relative displacement [m], relative
velocity [m/s], table acceleration [m/s^2]) are optional; a controller may
send none.  ``step`` of a REPLY is the step index of the COMMAND it answers
(the measurement at the end of that command's sample period).

Sequence checks (:class:`UdpBackend`): a REPLY is used only if it answers the
step being read, arrives before ``timeout_s`` and was not used before.  Others
are counted and dropped: ``lost`` (no reply in time; ``read()`` then returns
NaN so nothing stale is ever used), ``late`` (reply to an earlier step that
was already given up), ``duplicate`` (second copy of a used reply),
``out_of_order`` (reply labelled with a step not yet commanded), ``malformed``
(bad magic/version/kind/size).  The controller emulator
(:mod:`rths_actuator_bridge.emulator`) counts the same events for COMMAND
datagrams.
"""

import socket
import struct
import time

import numpy as np

from .backend import Backend

MAGIC = b'RTHS'
VERSION = 1
HEADER = struct.Struct('<4sBBHHQ')
COMMAND, REPLY, ACTIVATE, DEACTIVATE, ACK = 1, 2, 3, 4, 5
MAX_VALUES = 1024
STAT_KEYS = ('received', 'lost', 'late', 'duplicate', 'out_of_order', 'malformed')

#: UDP-backend parameters: key -> (type, default, meaning with unit).
UDP_PARAMS = {
    'host': (str, '127.0.0.1', 'IPv4 address of the servo controller'),
    'port': (int, 0, 'UDP port of the servo controller (1..65535)'),
    'local_port': (int, 0, 'local UDP port of the bridge (0 = any)'),
    'timeout_s': (float, 0.05, '[s] how long read() waits for the reply of the current step'),
    'n_channels': (int, 1, '[-] number of actuators'),
}
#: Ranges of the ports, timeout and channel count of :data:`UDP_PARAMS` (inclusive).
UDP_RANGES = {
    'port': (0, 65535),
    'local_port': (0, 65535),
    'timeout_s': (0.0, 10.0),
    'n_channels': (1, 64),
}


def pack(kind: int, step: int, values=(), n_channels: int = 1) -> bytes:
    """Encode one datagram."""
    vals = np.asarray(values, '<f8').ravel()
    return HEADER.pack(MAGIC, VERSION, kind, n_channels, vals.size, step) + vals.tobytes()


def unpack(data: bytes):
    """Decode one datagram -> ``(kind, step, n_channels, values)``; ValueError if malformed."""
    if len(data) < HEADER.size:
        raise ValueError(f'datagram of {len(data)} bytes is shorter than the header')
    magic, version, kind, n_ch, n_val, step = HEADER.unpack_from(data)
    if magic != MAGIC or version != VERSION:
        raise ValueError(f'bad magic/version {magic!r}/{version}')
    if kind not in (COMMAND, REPLY, ACTIVATE, DEACTIVATE, ACK) or n_val > MAX_VALUES:
        raise ValueError(f'bad kind {kind} or value count {n_val}')
    if len(data) != HEADER.size + 8 * n_val:
        raise ValueError(f'datagram size {len(data)} != {HEADER.size + 8 * n_val}')
    values = np.frombuffer(data, '<f8', count=n_val, offset=HEADER.size).astype(float)
    return kind, step, n_ch, values


def _params(params: dict, spec: dict) -> dict:
    out = {}
    for key, (typ, default, meaning) in spec.items():
        raw = params.get(key, default)
        try:
            out[key] = typ(raw)
        except (TypeError, ValueError):
            raise ValueError(f'parameter {key!r} = {raw!r} is not a {typ.__name__}: '
                             f'{meaning}') from None
    return out


class UdpBackend(Backend):
    """Backend talking to a servo controller over UDP (see module docstring)."""

    summary = 'a servo controller over UDP (the datagram protocol of udp.py)'
    params = UDP_PARAMS
    ranges = UDP_RANGES

    @classmethod
    def make_safe(cls, params: dict) -> str:
        """Send DEACTIVATE to the servo controller of ``params``; OSError without its ACK."""
        host, port = str(params.get('host', '127.0.0.1')), int(params.get('port', 0))
        n_channels = int(params.get('n_channels', 1))
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            sock.settimeout(0.2)
            for _ in range(5):
                sock.sendto(pack(DEACTIVATE, 0, (), n_channels), (host, port))
                try:
                    kind, *_ = unpack(sock.recvfrom(65536)[0])
                except (socket.timeout, ValueError):
                    continue
                if kind == ACK:
                    return (f'servo controller {host}:{port} acknowledged DEACTIVATE (actuator '
                            'stopped)')
        raise OSError(f'no ACK from {host}:{port}')

    def _configure(self, params: dict):
        p = _params(params, UDP_PARAMS)
        if not 1 <= p['port'] <= 65535:
            raise ValueError(f"parameter 'port' = {p['port']} must be the controller's UDP port "
                             '1..65535')
        if not p['timeout_s'] > 0:
            raise ValueError(f"parameter 'timeout_s' = {p['timeout_s']} must be > 0 s")
        if p['n_channels'] < 1:
            raise ValueError("parameter 'n_channels' must be >= 1")
        try:
            socket.inet_aton(p['host'])
        except OSError:
            raise ValueError(f"parameter 'host' = {p['host']!r} must be an IPv4 address "
                             '(e.g. 127.0.0.1)') from None
        self.params = p
        self.n_channels = p['n_channels']
        self.addr = (p['host'], p['port'])
        if getattr(self, 'sock', None) is not None:
            self.sock.close()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        local = '127.0.0.1' if p['host'].startswith('127.') else '0.0.0.0'
        self.sock.bind((local, p['local_port']))
        self.stats = dict.fromkeys(STAT_KEYS, 0)
        self._extra = np.zeros(0)
        self._used = set()

    def _recv(self, deadline: float):
        """Next well-formed datagram from the controller before ``deadline``, or None."""
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            self.sock.settimeout(left)
            try:
                data, addr = self.sock.recvfrom(65536)
            except socket.timeout:
                return None
            try:
                return unpack(data)
            except ValueError:
                self.stats['malformed'] += 1

    def _handshake(self, kind: int, required: bool):
        for _ in range(3):
            self.sock.sendto(pack(kind, 0, (), self.n_channels), self.addr)
            deadline = time.monotonic() + max(self.params['timeout_s'], 0.2)
            while True:
                msg = self._recv(deadline)
                if msg is None:
                    break
                if msg[0] == ACK:
                    return msg
                self.stats['late'] += 1   # replies of an earlier run
        if required:
            raise OSError(f'controller at {self.addr[0]}:{self.addr[1]} does not answer '
                          '(is it running? check host/port)')
        return None

    def _activate(self):
        self._handshake(ACTIVATE, True)
        self._used = set()
        self._reply_step = -1

    def _deactivate(self):
        self._handshake(DEACTIVATE, False)

    def _write(self, command):
        self.sock.sendto(pack(COMMAND, self.step, command, self.n_channels), self.addr)

    def _read(self):
        n = self.n_channels
        k = self.step
        deadline = time.monotonic() + self.params['timeout_s']
        while True:
            msg = self._recv(deadline)
            if msg is None:
                self.stats['lost'] += 1
                self._extra = np.zeros(0)
                return np.full(n, np.nan), np.full(n, np.nan)
            kind, step, n_ch, values = msg
            if kind != REPLY or n_ch != n or values.size < 2 * n:
                self.stats['malformed' if kind == REPLY else 'late'] += 1
                continue
            if step in self._used:
                self.stats['duplicate'] += 1
            elif step < k:
                self.stats['late'] += 1
            elif step > k:
                self.stats['out_of_order'] += 1
            else:
                self._used.add(step)
                self.stats['received'] += 1
                self._extra = values[2 * n:]
                return values[:n].copy(), values[n:2 * n].copy()

    def channels(self) -> dict:
        """Extra reply values of the latest step (emulator: rel_disp, rel_vel, table_accel)."""
        names = ('rel_disp', 'rel_vel', 'table_accel')
        return {name: float(v) for name, v in zip(names, self._extra, strict=False)}

    def close(self):
        """Deactivate and close the socket."""
        super().close()
        if getattr(self, 'sock', None) is not None:
            self.sock.close()
            self.sock = None
