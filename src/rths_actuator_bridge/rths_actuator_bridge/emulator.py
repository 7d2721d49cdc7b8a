"""The controller emulator: the simulated plant served behind the UDP protocol of :mod:`.udp`.

Lock-step: one plant sample per COMMAND step.  A COMMAND for an already
answered step is answered again from its cache (idempotent); gaps are filled
by holding the last command (ZOH), as a real controller running on its own
clock would.  ``rths controller-emulator`` runs it as a process.
"""

import socket
import threading

import numpy as np

from .simulated import SimulatedPlant, plant_config
from .udp import ACK, ACTIVATE, COMMAND, DEACTIVATE, REPLY, pack, unpack


class ControllerEmulator:
    """The simulated plant behind the UDP protocol (lock-step: one sample per COMMAND step).

    ``faults`` injects network faults into the REPLY stream for tests:
    ``{'drop': {steps}, 'duplicate': {steps}, 'delay_s': {step: seconds},
    'relabel': {step: other_step}, 'corrupt': {steps}}``.
    """

    def __init__(self, params: dict = None, host: str = '127.0.0.1', port: int = 0,
                 faults: dict = None):
        """Bind the socket and build the plant from flat simulated-backend ``params``."""
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
