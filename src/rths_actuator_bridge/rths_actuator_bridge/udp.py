"""UDP hardware backend and the controller emulator that runs the simulated plant behind it.

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
(bad magic/version/kind/size).  The emulator counts the same events for
COMMAND datagrams; a COMMAND for an already answered step is answered again
from its cache (idempotent), gaps are filled by holding the last command (ZOH),
as a real controller running on its own clock would.
"""

import socket
import struct
import threading
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
        return {name: float(v) for name, v in zip(names, self._extra)}

    def close(self):
        """Deactivate and close the socket."""
        super().close()
        if getattr(self, 'sock', None) is not None:
            self.sock.close()
            self.sock = None


class ControllerEmulator:
    """The simulated plant behind the UDP protocol (lock-step: one sample per COMMAND step).

    ``faults`` injects network faults into the REPLY stream for tests:
    ``{'drop': {steps}, 'duplicate': {steps}, 'delay_s': {step: seconds},
    'relabel': {step: other_step}, 'corrupt': {steps}}``.
    """

    def __init__(self, params: dict = None, host: str = '127.0.0.1', port: int = 0,
                 faults: dict = None):
        """Bind the socket and build the plant from flat simulated-backend ``params``."""
        from .simulated import SimulatedPlant, plant_config
        self.plant = SimulatedPlant(plant_config(params or {}))
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((host, port))
        self.address = self.sock.getsockname()
        self.faults = faults or {}
        self.stats = dict.fromkeys(('commands', 'lost', 'late', 'duplicate', 'malformed',
                                    'inactive'), 0)
        self.active = False
        self._stop = threading.Event()
        self._thread = None
        self._reset()

    def _reset(self):
        self.plant.reset()
        self.expected = 0
        self.last_command = 0.0
        self.cache = {}

    def _values(self):
        m = self.plant.measure()
        self._last_values = np.array([m['table_disp'], m['force'], m['rel_disp'], m['rel_vel'],
                                      m['table_accel']])
        return self._last_values

    def _send_reply(self, step, values, addr):
        f = self.faults
        if step in f.get('drop', ()):
            return
        label = f.get('relabel', {}).get(step, step)
        data = pack(REPLY, label, values)
        if step in f.get('corrupt', ()):
            data = b'XXXX' + data[4:]
        delay = f.get('delay_s', {}).get(step)
        if delay:
            threading.Timer(delay, self.sock.sendto, (data, addr)).start()
        else:
            self.sock.sendto(data, addr)
        if step in f.get('duplicate', ()):
            self.sock.sendto(data, addr)

    def handle(self, data: bytes, addr):
        """Process one datagram from the bridge at ``addr``."""
        try:
            kind, step, n_ch, values = unpack(data)
        except ValueError:
            self.stats['malformed'] += 1
            return
        if kind == ACTIVATE:
            self._reset()
            self.active = True
            self.sock.sendto(pack(ACK, 0, np.zeros(5)), addr)
        elif kind == DEACTIVATE:
            self.active = False
            self.sock.sendto(pack(ACK, 0, np.zeros(5)), addr)
        elif kind == COMMAND:
            if not self.active:
                self.stats['inactive'] += 1
                return
            if n_ch != 1 or values.size != 1 or not np.isfinite(values[0]):
                self.stats['malformed'] += 1
                return
            if step in self.cache:
                self.stats['duplicate'] += 1
                self._send_reply(step, self.cache[step], addr)
                return
            if step < self.expected:
                self.stats['late'] += 1
                return
            while self.expected < step:      # commands lost: hold the last one (ZOH)
                self.stats['lost'] += 1
                self.plant.step(self.last_command)
                self.expected += 1
            self.last_command = float(values[0])
            self.plant.step(self.last_command)
            self.expected = step + 1
            self.stats['commands'] += 1
            vals = self._values()
            self.cache[step] = vals
            self.cache.pop(step - 64, None)
            self._send_reply(step, vals, addr)

    def serve_forever(self, poll_s: float = 0.1):
        """Answer datagrams until :meth:`stop`."""
        self.sock.settimeout(poll_s)
        while not self._stop.is_set():
            try:
                data, addr = self.sock.recvfrom(65536)
            except socket.timeout:
                continue
            except OSError:
                break
            self.handle(data, addr)

    def start(self):
        """Serve in a daemon thread; returns self."""
        self._thread = threading.Thread(target=self.serve_forever, daemon=True)
        self._thread.start()
        return self

    def stop(self):
        """Stop serving and close the socket."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
        self.sock.close()

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.stop()
