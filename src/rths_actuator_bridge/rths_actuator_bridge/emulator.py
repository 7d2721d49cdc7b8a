"""The controller emulator: the reference servo controller of ``docs/controller_protocol.md``.

It serves the simulated plant (one actuator + table + specimen per channel)
behind the datagram protocol of :mod:`.protocol`, versions 1 and 2 (it answers
in the version of the ACTIVATE it got).  Behaviour a lab controller must have,
as the document states it:

* ACTIVATE resets the step count, not the actuator (the plant keeps its
  state); the ACK carries the emulator's own channel count, and in version 2
  the current reading, the reply channel names, a session number drawn at
  start-up and the status ACTIVE.  A channel count or sampling rate that
  differs from its own is refused (version 2: fault in the ACK).
* COMMAND k: applied for one sample, answered with the reading at its end
  (REPLY k).  A COMMAND repeated is answered again from a cache without
  moving the plant; an older one is ignored; missing steps are held (ZOH).
  A command beyond the emulator's own limits (``stroke_m``, ``velocity_m_s``)
  is not applied: the last one is held and the REPLY says LIMITED (version 2).
* ``wall_clock``: the plant follows the emulator's own clock at ``fs_hz`` (a
  real actuator keeps moving while the bridge is late: missed samples hold
  the last command); with no COMMAND for ``interlock_s`` after the first one,
  its interlock ramps the actuator to rest on its own and it goes inactive.
* DEACTIVATE (from the session's host, any port, any version): inactive.

Faults for tests and the conformance checker (:data:`FAULT_KEYS`; steps are
COMMAND steps of the session): ``drop_every`` N (no reply to steps k > 0 with
k % N == 0), ``late_every`` N (that reply ``late_s`` late), ``malformed_at`` K
(a malformed datagram instead of REPLY K), ``silence_at`` K (from COMMAND K
nothing is read or sent for ``silence_s``), ``restart_at`` K (at COMMAND K it
reboots: silent for ``restart_s``, then inactive with a new session), and
the per-step sets ``drop``, ``duplicate``, ``corrupt``, ``delay_s``, ``relabel``.
``rths controller-emulator`` runs it as a process.
"""

import math
import os
import random
import socket
import threading
import time

import numpy as np

from . import protocol as p
from .simulated import SimulatedPlant, plant_config

#: Fault keys of :class:`ControllerEmulator` with their off values.
FAULT_KEYS = {'drop_every': 0, 'late_every': 0, 'late_s': 0.002, 'malformed_at': -1,
              'silence_at': -1, 'silence_s': 0.3, 'restart_at': -1, 'restart_s': 0.2,
              'drop': (), 'duplicate': (), 'corrupt': (), 'delay_s': {}, 'relabel': {}}
#: The specimen channels the emulator names after displacement and force.
EXTRA = ('rel_disp', 'rel_vel', 'table_accel')
#: Steps of replies kept to answer a repeated COMMAND.
CACHE_STEPS = 64


def realtime_thread(priority: int) -> str:
    """SCHED_FIFO ``priority`` for the calling thread, as a real-time controller runs; describe."""
    if priority <= 0:
        return 'normal scheduling'
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        return f'SCHED_FIFO {priority}'
    except (OSError, AttributeError) as err:
        return f'SCHED_FIFO {priority} refused ({err})'


class ControllerEmulator:
    """The simulated plant behind the controller protocol (see the module docstring)."""

    def __init__(self, params: dict = None, host: str = '127.0.0.1', port: int = 0,
                 faults: dict = None, n_channels: int = 1, stroke_m: float = 0.254,
                 velocity_m_s: float = 2.0, wall_clock: bool = False, interlock_s: float = 0.1,
                 rt_priority: int = 0):
        """Bind the socket and build one plant per channel from flat simulated ``params``."""
        unknown = set(faults or {}) - set(FAULT_KEYS)
        if unknown:
            raise ValueError(f'emulator faults {sorted(unknown)} are unknown; use '
                             f'{", ".join(FAULT_KEYS)}')
        if not 1 <= int(n_channels) <= 64:
            raise ValueError(f'--channels {n_channels} must lie in 1..64')
        for name, value in (('stroke_m', stroke_m), ('velocity_m_s', velocity_m_s),
                            ('interlock_s', interlock_s)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f'emulator {name} = {value} must be a positive number')
        config = plant_config(params or {})
        self.fs_hz = config.fs_hz
        self.plants = [SimulatedPlant(config) for _ in range(int(n_channels))]
        self.n_channels = int(n_channels)
        self.names = p.default_names(self.n_channels, ('displacement', 'force') + EXTRA)
        self.stroke_m, self.velocity_m_s = float(stroke_m), float(velocity_m_s)
        self.wall_clock, self.interlock_s = bool(wall_clock), float(interlock_s)
        self.rt_priority = int(rt_priority)
        self.faults = dict(FAULT_KEYS, **(faults or {}))
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((host, port))
        self.address = self.sock.getsockname()
        self.stats = dict.fromkeys(('commands', 'lost', 'late', 'duplicate', 'malformed',
                                    'inactive', 'limited', 'foreign', 'interlocks'), 0)
        self.session = random.getrandbits(32) or 1
        self.sequence = 0
        self.active = False
        self.peer = None
        self.version = 1
        self.status = 0
        self.fault, self.fault_msg = p.F_NONE, ''
        self.quiet_until = 0.0          # silence / reboot: nothing is read or sent until then
        self.rebooting = False
        self._stop = threading.Event()
        self._thread = None
        self.held = np.zeros(self.n_channels)   # the command the actuator holds
        self._last = None               # the readings of the latest sample, per channel
        self._start_session()

    # ---------------------------------------------------------------- state
    def _start_session(self):
        self.expected = 0
        self.cache = {}
        self.t_first = None             # wall time of the session's first COMMAND
        self.t_last = None              # ... and of the latest one
        self.samples = 0                # plant samples taken in this session

    def _reading(self) -> np.ndarray:
        """Return the REPLY values of the latest sample (before any: the true state, no noise)."""
        m = self._last or [dict(plant.true) for plant in self.plants]
        per = {'displacement': [x['table_disp'] for x in m], 'force': [x['force'] for x in m],
               **{q: [x[q] for x in m] for q in EXTRA}}
        return np.array([v for q in ('displacement', 'force') + EXTRA for v in per[q]])

    def _sample(self, command):
        for plant, u in zip(self.plants, command, strict=True):
            plant.step(float(u))
        self._last = [plant.measure() for plant in self.plants]
        self.samples += 1

    def _catch_up(self, now: float):
        """Wall clock: take the samples that passed since the session's first COMMAND."""
        if not self.wall_clock or self.t_first is None:
            return
        due = int((now - self.t_first) * self.fs_hz)
        while self.samples < due:
            if self.status & p.ST_HOLDING:      # the interlock brings the actuator to rest
                step = self.velocity_m_s * 0.5 / self.fs_hz
                self.held = self.held - np.clip(self.held, -step, step)
            self._sample(self.held)

    def _limit(self, u: np.ndarray) -> str:
        if not np.all(np.isfinite(u)):
            return f'non-finite command {u.tolist()}'
        if np.any(np.abs(u) > self.stroke_m):
            return (f'command {float(np.max(np.abs(u))):.6g} m beyond the stroke '
                    f'+-{self.stroke_m:g} m')
        v = float(np.max(np.abs(u - self.held))) * self.fs_hz
        if v > self.velocity_m_s:
            return f'command velocity {v:.6g} m/s above {self.velocity_m_s:g} m/s'
        return ''

    # ---------------------------------------------------------------- sending
    def _pack(self, kind, step, values=(), status=None, fault=None, text='', n_channels=None):
        self.sequence += 1
        if self.version == 1:
            return p.pack(kind, step, values, n_channels or self.n_channels)
        return p.pack(kind, step, values, n_channels or self.n_channels, version=2,
                      session=self.session, sequence=self.sequence,
                      status=self.status if status is None else status,
                      fault=self.fault if fault is None else fault, text=text)

    def _send(self, data, addr):
        try:
            self.sock.sendto(data, addr)
        except OSError:
            pass

    def _send_reply(self, step, data, addr):
        f = self.faults
        if step in f['drop'] or (f['drop_every'] and step > 0 and step % f['drop_every'] == 0):
            return
        if step == f['malformed_at'] or step in f['corrupt']:
            data = b'XXXX' + data[4:]
        delay = f['delay_s'].get(step)
        if f['late_every'] and step > 0 and step % f['late_every'] == 0:
            delay = f['late_s']
        if delay:
            threading.Timer(delay, self._send, (data, addr)).start()
        else:
            self._send(data, addr)
        if step in f['duplicate']:
            self._send(data, addr)

    # ---------------------------------------------------------------- datagrams
    def handle(self, data: bytes, addr, now: float = None):
        """Process one datagram from ``addr`` received at ``now`` (monotonic)."""
        now = time.monotonic() if now is None else now
        if now < self.quiet_until:
            return
        if self.rebooting:              # back from the reboot: inactive, a new session
            self.rebooting = False
            self.active, self.status, self.peer = False, 0, None
            self.fault, self.fault_msg = p.F_NONE, ''
            self.session = random.getrandbits(32) or 1
        try:
            d = p.unpack(data)
        except ValueError:
            self.stats['malformed'] += 1
            return
        if d.kind == p.ACTIVATE:
            self._activate(d, addr)
        elif d.kind == p.DEACTIVATE:
            if self.peer is not None and addr[0] != self.peer[0]:
                self.stats['foreign'] += 1
                return
            self.version = d.version
            self._catch_up(now)
            self.active = False
            self.status &= ~p.ST_ACTIVE
            self._send(self._pack(p.ACK, 0, self._reading()), addr)
        elif d.kind == p.HEARTBEAT:
            self._send(self._pack(p.HEARTBEAT, d.step, text=','.join(self.names)), addr)
        elif d.kind == p.COMMAND:
            self._command(d, addr, now)

    def _activate(self, d, addr):
        self.version = d.version
        if d.n_channels != self.n_channels:
            self.active, self.status = False, 0
            text = (f'{d.n_channels} channel(s) asked, this controller has {self.n_channels} '
                    'channel(s)')
            self._send(self._pack(p.ACK, 0, (), status=p.ST_FAULT, fault=p.F_CHANNELS,
                                  text=text if d.version == 2 else ''), addr)
            return
        if d.version == 2 and d.values.size and d.values[0] and d.values[0] != self.fs_hz:
            self.active, self.status = False, 0
            self._send(self._pack(p.ACK, 0, (), status=p.ST_FAULT, fault=p.F_RATE,
                                  text=f'the bridge runs at {d.values[0]:g} Hz, this '
                                       f'controller at {self.fs_hz:g} Hz'), addr)
            return
        self.active, self.peer = True, addr
        self.status, self.fault = p.ST_ACTIVE, p.F_NONE
        self._start_session()
        text = ','.join(self.names) if self.version == 2 else ''
        self._send(self._pack(p.ACK, 0, self._reading(), text=text), addr)

    def _command(self, d, addr, now):
        f = self.faults
        if self.active and addr != self.peer:
            self.stats['foreign'] += 1
            return
        if d.step == f['restart_at'] and self.active:
            f['restart_at'] = -1
            self.quiet_until = now + f['restart_s']
            self.rebooting = True
            return
        if d.step == f['silence_at'] and self.active:
            f['silence_at'] = -1
            self.quiet_until = now + f['silence_s']
            return
        self._interlock_check(now)
        if not self.active or (d.version == 2 and d.session != self.session):
            self.stats['inactive'] += 1
            if d.version == 2:
                self._send(self._pack(p.REPLY, d.step, (), status=self.status & ~p.ST_ACTIVE,
                                      fault=self.fault or p.F_NOT_ACTIVE,
                                      text=self.fault_msg or 'send ACTIVATE'), addr)
            return
        if d.n_channels != self.n_channels or d.values.size != self.n_channels:
            self.stats['malformed'] += 1
            return
        if d.step in self.cache:
            self.stats['duplicate'] += 1
            self._send_reply(d.step, self.cache[d.step], addr)
            return
        if d.step < self.expected:
            self.stats['late'] += 1
            return
        if self.t_first is None:
            self.t_first = now
        self._catch_up(now)
        if not self.wall_clock:
            while self.expected < d.step:       # commands lost: hold the last one (ZOH)
                self.stats['lost'] += 1
                self._sample(self.held)
                self.expected += 1
        self.t_last = now
        text = self._limit(d.values)
        status, fault = self.status, p.F_NONE
        if text:
            self.stats['limited'] += 1
            status, fault = status | p.ST_LIMITED, p.F_LIMIT
        else:
            self.held = d.values.copy()
        self._sample(self.held)
        self.expected = d.step + 1
        self.stats['commands'] += 1
        label = f['relabel'].get(d.step, d.step)
        data = self._pack(p.REPLY, label, self._reading(), status=status, fault=fault,
                          text=text if self.version == 2 else '')
        self.cache[d.step] = data
        self.cache.pop(d.step - CACHE_STEPS, None)
        self._send_reply(d.step, data, addr)

    def _interlock_check(self, now):
        """Wall clock: no COMMAND for ``interlock_s``: bring the actuator to rest, go inactive."""
        if (self.wall_clock and self.active and self.t_last is not None
                and now - self.t_last > self.interlock_s):
            self._catch_up(self.t_last + self.interlock_s)
            self.stats['interlocks'] += 1
            self.active = False
            self.status = p.ST_HOLDING | p.ST_FAULT
            self.fault, self.fault_msg = p.F_INTERLOCK, (
                f'no COMMAND for {self.interlock_s:g} s: actuator brought to rest')
            self._catch_up(now)

    # ---------------------------------------------------------------- serving
    def serve_forever(self, poll_s: float = 0.01):
        """Answer datagrams until :meth:`stop` (the interlock is checked every ``poll_s``)."""
        realtime_thread(self.rt_priority)
        self.sock.settimeout(poll_s)
        while not self._stop.is_set():
            try:
                data, addr = self.sock.recvfrom(65536)
            except socket.timeout:
                self._interlock_check(time.monotonic())
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
