"""A lab's own servo controller, written from docs/controller_protocol.md alone.

Independent of the rths code on purpose (only the standard library): it stands for the
controller a lab writes for its Speedgoat or LabVIEW box, so the tests check the document,
not the emulator.  Versions 1 and 2; one actuator (a first-order lag, time constant
``TAU_S``) carrying a spring-damper specimen; REPLY values: displacement, force and an extra
``pressure`` (named in version 2; in version 1 the bridge ignores the value nobody named).

``versions=(1,)`` is a controller written against version 1 only (it ignores version-2
datagrams).  Faults, as a lab's controller has them: no REPLY to every ``drop_every``-th
step, the REPLY of every ``late_every``-th step sent ``late_s`` late, a malformed datagram
instead of the REPLY of step ``malformed_at``, and ``silence_s`` of silence from COMMAND
``silence_at``.
"""

import random
import socket
import struct
import threading
import time

V1 = struct.Struct('<4sBBHHQ')          # magic, version, kind, n_channels, n_values, step
V2 = struct.Struct('<4sBBHHQIIHH')      # ... session, sequence, status, fault
COMMAND, REPLY, ACTIVATE, DEACTIVATE, ACK, HEARTBEAT = 1, 2, 3, 4, 5, 6
ACTIVE, LIMITED, FAULT = 0x1, 0x4, 0x8
TAU_S = 0.004                          # [s] actuator time constant
STIFFNESS, DAMPING = 2000.0, 40.0      # [N/m], [N s/m] of the specimen
STROKE = 0.2                           # [m] the controller's own stroke limit
NAMES = 'displacement,force,pressure'


class LabController:
    """Serve the protocol on 127.0.0.1 in a thread (``port`` after :meth:`start`)."""

    def __init__(self, versions=(1, 2), fs_hz=1024.0, drop_every=0, late_every=0, late_s=0.002,
                 malformed_at=-1, silence_at=-1, silence_s=0.3):
        self.versions = versions       # (1,): a controller written against version 1 only
        self.fs = fs_hz
        self.drop_every, self.late_every, self.late_s = drop_every, late_every, late_s
        self.malformed_at, self.silence_at, self.silence_s = malformed_at, silence_at, silence_s
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(('127.0.0.1', 0))
        self.port = self.sock.getsockname()[1]
        self.session = random.randrange(1, 2 ** 32)
        self.sequence = 0
        self.version = 1
        self.active = False
        self.peer = None
        self.x = self.v = 0.0          # actuator position [m], velocity [m/s]
        self.u = 0.0                   # the command held
        self.next_step = 0
        self.answered = {}             # step -> datagram (a repeated COMMAND)
        self.quiet_until = 0.0
        self.pending = []              # (send time, datagram, address): late replies
        self.counts = {'commands': 0, 'dropped': 0, 'late': 0, 'malformed': 0}
        self.running = False

    # -------------------------------------------------------------- the document's datagrams
    def _datagram(self, kind, step, values=(), status=0, fault=0, text=''):
        body = struct.pack(f'<{len(values)}d', *values)
        if self.version == 1:
            return V1.pack(b'RTHS', 1, kind, 1, len(values), step) + body
        self.sequence += 1
        return (V2.pack(b'RTHS', 2, kind, 1, len(values), step, self.session,
                        self.sequence & 0xFFFFFFFF, status, fault) + body + text.encode())

    def _readings(self):
        force = STIFFNESS * self.x + DAMPING * self.v
        return (self.x, force, 101325.0 + 10.0 * force)

    def _sample(self):
        """One sample with the held command (exact first-order lag)."""
        import math
        a = math.exp(-1.0 / (self.fs * TAU_S))
        x = self.u + (self.x - self.u) * a
        self.v = (x - self.x) * self.fs
        self.x = x

    # -------------------------------------------------------------- handling
    def handle(self, data, addr):
        """Answer one datagram as the document says."""
        now = time.monotonic()
        if now < self.quiet_until or len(data) < V1.size or data[:4] != b'RTHS':
            return
        version, kind = data[4], data[5]
        if version not in self.versions:
            return
        header = V1 if version == 1 else V2
        if len(data) < header.size:
            return
        fields = header.unpack_from(data)
        n_ch, n_val, step = fields[3], fields[4], fields[5]
        values = struct.unpack_from(f'<{n_val}d', data, header.size)
        if kind == ACTIVATE:
            self.version = version
            self.active, self.peer = True, addr
            self.next_step, self.answered = 0, {}
            self.sock.sendto(self._datagram(ACK, 0, self._readings(), ACTIVE, 0, NAMES), addr)
        elif kind == DEACTIVATE and self.peer and addr[0] == self.peer[0]:
            self.active = False
            self.sock.sendto(self._datagram(ACK, 0, self._readings(), 0), addr)
        elif kind == HEARTBEAT and version == 2:
            self.sock.sendto(self._datagram(HEARTBEAT, 0, (), ACTIVE if self.active else 0, 0,
                                            NAMES), addr)
        elif kind == COMMAND:
            self._command(step, n_ch, values, version, fields, addr, now)

    def _command(self, step, n_ch, values, version, fields, addr, now):
        if not self.active or addr != self.peer or (version == 2 and fields[6] != self.session):
            if version == 2:
                self.sock.sendto(self._datagram(REPLY, step, (), 0, 4, 'send ACTIVATE'), addr)
            return
        if step == self.silence_at:
            self.silence_at = -1
            self.quiet_until = now + self.silence_s
            return
        if step in self.answered:
            self.sock.sendto(self.answered[step], addr)
            return
        if step < self.next_step or n_ch != 1 or len(values) != 1:
            return
        while self.next_step < step:          # skipped steps hold the last command
            self._sample()
            self.next_step += 1
        status, fault, text = ACTIVE, 0, ''
        if abs(values[0]) <= STROKE and values[0] == values[0]:
            self.u = values[0]
        else:
            status, fault, text = ACTIVE | LIMITED | FAULT, 1, 'stroke'
        self._sample()
        self.next_step = step + 1
        self.counts['commands'] += 1
        reply = self._datagram(REPLY, step, self._readings(), status, fault, text)
        self.answered[step] = reply
        self.answered.pop(step - 64, None)
        if self.drop_every and step > 0 and step % self.drop_every == 0:
            self.counts['dropped'] += 1
        elif step == self.malformed_at:
            self.counts['malformed'] += 1
            self.sock.sendto(b'RTHS\x07' + reply[5:], addr)        # an unknown version
        elif self.late_every and step > 0 and step % self.late_every == 0:
            self.counts['late'] += 1
            self.pending.append((now + self.late_s, reply, addr))
        else:
            self.sock.sendto(reply, addr)

    # -------------------------------------------------------------- serving
    def _serve(self):
        try:    # a lab's controller is real time: SCHED_FIFO where the system allows it
            import os
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(50))
        except (OSError, AttributeError):
            pass
        while self.running:
            timeout = 0.01
            if self.pending:    # (a timeout of 0 would make the socket non-blocking)
                timeout = max(1e-5, min(t for t, _, _ in self.pending) - time.monotonic())
            self.sock.settimeout(timeout)
            try:
                data, addr = self.sock.recvfrom(2048)
                self.handle(data, addr)
            except (socket.timeout, BlockingIOError):
                pass
            except OSError:
                return
            now = time.monotonic()
            for item in [p for p in self.pending if p[0] <= now]:
                self.pending.remove(item)
                self.sock.sendto(item[1], item[2])

    def start(self):
        """Serve in a daemon thread; returns self."""
        self.running = True
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()
        return self

    def stop(self):
        """Stop serving."""
        self.running = False
        self.thread.join(2.0)
        self.sock.close()
