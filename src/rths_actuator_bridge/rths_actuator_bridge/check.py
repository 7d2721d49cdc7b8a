"""``rths controller-check``: conformance of a lab's servo controller to the controller protocol.

:func:`check_controller` talks to the controller as the bridge would
(``docs/controller_protocol.md``) and returns a report: one entry per check
with ``passed``, a one-line ``detail`` naming what is wrong, and figures.
The checks, in order:

``activate``   ACTIVATE (version 2, else 1) is acknowledged, with the channel count asked;
               a version-2 ACK is ACTIVE and names a displacement and force per channel.
``sequence``   ``steps`` COMMANDs at the loop rate: exactly one usable REPLY per step, in
               time (before the next tick), labelled with its step; lost, late, malformed,
               duplicate and out-of-order replies are counted with their steps (a regular
               pattern is named, e.g. every 500th step), the reply time's distribution is
               given, and a silence (consecutive lost replies) is measured.
``restart``    the controller kept its session and stayed ACTIVE through the sequence.
``late_command``       a COMMAND sent 10 periods late is answered.
``duplicate_command``  a COMMAND sent twice is answered twice with the same values, and the
               next one normally.
``heartbeat``  (version 2) a HEARTBEAT is answered with the session and status ACTIVE.
``deactivate`` DEACTIVATE is acknowledged; a COMMAND after it is not answered as ACTIVE.

The channel count is ``--channels`` or, with ``--rig-file``, the rig file's number of
actuators (:func:`rig_channels`), the count the bridge's UDP backend uses for that file.

The commands hold the actuator where the ACK says it is (version 1: at 0 m), plus an
optional sine of ``amplitude_m``.  Reply times are taken from the kernel's receive time
stamps (SO_TIMESTAMPNS), so the checker's own scheduling does not make a reply late; the
checker's own send lateness is reported as ``send_late_ms_max`` (the floor of the figures).
"""

import math
import os
import select
import socket
import struct
import time

import numpy as np

from rths_common.rig import load_rig

from . import protocol as p

#: A reply later than this many sample periods after its COMMAND is late (it missed the tick).
LATE_PERIODS = 1.0
#: Late replies tolerated in the sequence, as a fraction of its steps: scattered
#: scheduling outliers (a regular pattern always fails).
LATE_TOLERANCE = 0.001
#: Consecutive lost replies that make a silence rather than single losses.
SILENCE_STEPS = 10
#: Linux's SO_TIMESTAMPNS (= SCM_TIMESTAMPNS; not exported by Python 3.11's socket module).
SO_TIMESTAMPNS = getattr(socket, 'SO_TIMESTAMPNS', 35)


def periodic(steps, total: int):
    """Return N if the multiples k > 0 of some N < total are in ``steps``, else 0.

    At least 3 multiples, all of them or all but one (of four or more).  A
    controller fault that repeats (every 200th reply late) stands out from the
    scattered outliers of a loaded machine this way.  The smallest such N is
    returned (it explains the most steps).
    """
    found = set(steps)
    for n in sorted({k for k in found if k > 0}):
        multiples = range(n, total, n)
        hits = sum(k in found for k in multiples)
        if hits >= 3 and hits >= len(multiples) - (1 if len(multiples) >= 4 else 0):
            return n
    return 0


def pattern(steps, total: int = 0) -> str:
    """Describe a list of steps: 'steps 500, 1000, 1500 (every 500th step)'."""
    steps = sorted(steps)
    every = periodic(steps, total) if total else 0
    shown = [k for k in steps if every and k % every == 0] or steps
    text = ', '.join(str(s) for s in shown[:6]) + (', ...' if len(shown) > 6 else '')
    if every:
        others = len(steps) - len(shown)
        text += f' (every {every}th step' + (f'; {others} other(s)' if others else '') + ')'
    return f'step{"s" if len(steps) > 1 else ""} {text}'


class Client:
    """The checker's side of the protocol: one socket, kernel receive times."""

    def __init__(self, host: str, port: int, channels: int, timeout_s: float):
        socket.inet_aton(host)
        self.addr = (host, port)
        self.channels = channels
        self.timeout_s = timeout_s
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        except OSError:      # no kernel time stamps here: the receive call's time is used
            pass
        self.sock.bind(('', 0))
        self.version = 1
        self.session = 0
        self.sequence = 0

    def send(self, kind: int, step: int, values=(), version: int = None) -> int:
        """Send one datagram; return the wall time [ns] just before it left."""
        self.sequence += 1
        data = p.pack(kind, step, values, self.channels, version=version or self.version,
                      session=self.session, sequence=self.sequence)
        t = time.time_ns()
        self.sock.sendto(data, self.addr)
        return t

    def receive(self, until: float):
        """Yield ``(t_ns, raw bytes)`` of datagrams from the controller until ``until``."""
        while True:
            left = until - time.monotonic()
            ready, _, _ = select.select([self.sock], [], [], max(left, 0.0))
            if not ready:
                return
            data, anc, _, addr = self.sock.recvmsg(65536, 64)
            if addr != self.addr:
                continue
            t = time.time_ns()
            for level, kind, raw in anc:
                if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS:
                    sec, nsec = struct.unpack('qq', raw[:16])
                    t = sec * 1_000_000_000 + nsec
            yield t, data

    def request(self, kind: int, step: int = 0, values=(), version: int = None, want=None):
        """Send ``kind`` and return the first decodable answer of kind ``want`` (or None)."""
        t = self.send(kind, step, values, version)
        for t_in, data in self.receive(time.monotonic() + self.timeout_s):
            try:
                d = p.unpack(data)
            except ValueError:
                continue
            if want is None or d.kind == want:
                return d, (t_in - t) * 1e-6
        return None, None

    def close(self):
        """Close the socket."""
        self.sock.close()


def rig_channels(rig_file: str = '', channels: int = None, amplitude_m: float = 0.0):
    """``(channels, actuator names)`` of the check: the rig file's, or ``channels`` (1).

    With a rig file (``rths_common.rig``, docs/multi_actuator.md) the channel count is its
    number of actuators, as the bridge's UDP backend uses it; a ``channels`` given as well
    must agree, and ``amplitude_m`` must stay within every actuator's stroke limit.  The
    errors name the file or the option and the fix.
    """
    if not rig_file:
        return (1 if channels is None else int(channels)), None
    try:
        rig = load_rig(rig_file)
    except OSError as err:
        raise ValueError(f'--rig-file: {err}; give the path of a rig file '
                         '(config/rig_two_actuators.yaml)') from None
    if channels is not None and int(channels) != rig.n:
        raise ValueError(f'--channels {channels} but {rig.where} has {rig.n} actuators '
                         f'({", ".join(rig.actuators)}); drop --channels (the file sets it)')
    for name, stroke in zip(rig.actuators, rig.limits['stroke_m'], strict=True):
        if stroke is not None and amplitude_m > stroke:
            raise ValueError(f'--amplitude-m {amplitude_m:g} exceeds actuator {name}\'s '
                             f'stroke_m {stroke:g} m in {rig.where}; give a smaller amplitude')
    return rig.n, list(rig.actuators)


def _entry(name, passed, detail, **figures):
    return {'name': name, 'passed': bool(passed), 'detail': detail, **figures}


def check_controller(host: str, port: int, channels: int = 1, fs_hz: float = 1024.0,
                     steps: int = 2048, version: int = 0, amplitude_m: float = 0.0,
                     timeout_s: float = 0.3, late_tolerance: float = LATE_TOLERANCE,
                     rt_priority: int = 0, progress=None) -> dict:
    """Run the checks of the module docstring; return the report (``passed``, ``checks``).

    ``late_tolerance``: the fraction of the sequence's replies that may be late,
    scattered (a regular pattern of late replies always fails).  ``rt_priority``
    > 0: the checker's thread runs SCHED_FIFO at that priority meanwhile.
    """
    if not 1 <= channels <= 64:
        raise ValueError(f'--channels {channels} must lie in 1..64')
    if not (math.isfinite(fs_hz) and 1 <= fs_hz <= 100_000):
        raise ValueError(f'--fs-hz {fs_hz} must lie in 1..100000 Hz')
    if steps < 100:
        raise ValueError(f'--steps {steps} must be >= 100')
    if not 0 <= late_tolerance < 1:
        raise ValueError(f'--late-tolerance-pct {100 * late_tolerance:g} must lie in [0, 100)')
    if not (math.isfinite(amplitude_m) and 0 <= amplitude_m <= 0.01):
        raise ValueError(f'--amplitude-m {amplitude_m} must lie in 0..0.01 m')
    say = progress or (lambda text: None)
    previous = (os.sched_getscheduler(0), os.sched_getparam(0))
    if rt_priority > 0:
        # lazy: start-up cost: SciPy (~1 s), which this module needs only here
        from .emulator import realtime_thread
        say(realtime_thread(rt_priority))
    try:
        return _check(host, port, channels, fs_hz, steps, version, amplitude_m, timeout_s,
                      late_tolerance, say)
    finally:
        if rt_priority > 0:
            try:
                os.sched_setscheduler(0, *previous)
            except OSError:
                pass


def _check(host, port, channels, fs_hz, steps, version, amplitude_m, timeout_s,
           late_tolerance, say) -> dict:
    client = Client(host, port, channels, timeout_s)
    report = {'controller': f'{host}:{port}', 'channels': channels, 'fs_hz': fs_hz,
              'steps': steps, 'late_tolerance_pct': 100 * late_tolerance, 'checks': []}
    checks = report['checks']
    try:
        say('ACTIVATE')
        act = _activate(client, channels, fs_hz, version)
        checks.append(act)
        report.update(protocol_version=client.version, reply_names=act.get('reply_names'))
        if act['passed']:
            say(f'{steps} COMMANDs at {fs_hz:g} Hz')
            seq, restart, last = _sequence(client, act, fs_hz, steps, amplitude_m,
                                           late_tolerance)
            checks += [seq, restart]
            report['latency_ms'] = seq.get('latency_ms')
            say('late and duplicate COMMANDs, HEARTBEAT, DEACTIVATE')
            checks.append(_late_command(client, act, last + 1, fs_hz))
            checks.append(_duplicate_command(client, act, last + 2))
            if client.version == 2:
                checks.append(_heartbeat(client))
            checks.append(_deactivate(client, act, last + 4))
    finally:
        client.close()
    failed = [c for c in checks if not c['passed']]
    report['passed'] = not failed
    report['fault'] = '; '.join(f"{c['name']}: {c['detail']}" for c in failed)
    return report


def _activate(client, channels, fs_hz, version):
    versions = (2, 1) if version == 0 else (version,)
    ack = latency = None
    for _ in range(3):
        for v in versions:
            ack, latency = client.request(p.ACTIVATE, 0, (fs_hz,) if v == 2 else (), v, p.ACK)
            if ack is not None:
                break
        if ack is not None:
            break
    if ack is None:
        return _entry('activate', False, f'no ACK to ACTIVATE (version '
                      f'{" or ".join(map(str, versions))}) within {client.timeout_s:g} s')
    client.version, client.session = ack.version, ack.session
    figures = {'version': ack.version, 'ack_ms': round(latency, 3),
               'controller_channels': ack.n_channels}
    if ack.n_channels != channels:
        return _entry('activate', False, f'the controller has {ack.n_channels} channel(s), '
                      f'{channels} asked' + (f' ({ack.text})' if ack.text else ''), **figures)
    if ack.version == 1:
        names = p.default_names(channels)
        return _entry('activate', True, f'version 1 ACK, {channels} channel(s); reply values '
                      'are not named in version 1 (the bridge reads displacement, force per '
                      'channel, or reply_names)', reply_names=names, n_values=None,
                      position=[0.0] * channels, **figures)
    if not ack.active or ack.fault:
        return _entry('activate', False, f'ACK not ACTIVE: {p.fault_text(ack) or "status "}'
                      f'{ack.status:#x}', **figures)
    try:
        index = p.parse_names(ack.text, channels)
    except ValueError as err:
        return _entry('activate', False, f'unusable reply names in the ACK: {err}', **figures)
    names = ack.text.split(',')
    position = [0.0] * channels
    if ack.values.size == len(names):
        position = [float(ack.values[index[('displacement', c)]]) for c in range(channels)]
    return _entry('activate', True, f'version 2 ACK, session {ack.session:#010x}, {channels} '
                  f'channel(s), reply values {ack.text}', reply_names=names,
                  n_values=len(names), position=position, **figures)


def _usable(d, client, act) -> str:
    """'' if ``d`` is a usable REPLY of this session, else why not."""
    if d.kind != p.REPLY:
        return f'a {p.KIND_NAMES[d.kind]} instead of a REPLY'
    if d.version != client.version:
        return f'version {d.version} in a version-{client.version} session'
    if d.n_channels != client.channels:
        return f'{d.n_channels} channel(s)'
    n = act['n_values']
    if (n is not None and d.values.size != n) or d.values.size < 2 * client.channels:
        return f'{d.values.size} values'
    if not np.all(np.isfinite(d.values)):
        return 'non-finite values'
    return ''


def _sequence(client, act, fs_hz, steps, amplitude_m, late_tolerance):
    period = 1.0 / fs_hz
    position = np.asarray(act['position'], float)
    sent, send_late = {}, []
    arrivals = []            # (t_ns, raw)
    t0 = time.monotonic() + 0.01
    for k in range(steps):
        due = t0 + k * period
        arrivals += list(client.receive(due))
        send_late.append(time.monotonic() - due)
        u = position + amplitude_m * math.sin(2 * math.pi * 1.0 * k * period)
        sent[k] = client.send(p.COMMAND, k, u)
    arrivals += list(client.receive(time.monotonic() + client.timeout_s))
    return _analyse(client, act, sent, arrivals, period, steps, send_late, late_tolerance)


def _analyse(client, act, sent, arrivals, period, steps, send_late, late_tolerance):
    used, latency, late, duplicate, out_of_order = {}, {}, [], [], []
    malformed, inactive, sessions, limited, sequences = [], [], set(), [], []
    for t, raw in arrivals:
        try:
            d = p.unpack(raw)
        except ValueError as err:
            step = int.from_bytes(raw[10:18], 'little') if len(raw) >= 18 else None
            malformed.append((step, str(err)))
            continue
        if d.version == 2:
            sequences.append(d.sequence)
            if d.session != client.session:
                sessions.add(d.session)
            if d.session != client.session or not d.active:
                inactive.append((d.step, p.fault_text(d) or f'status {d.status:#x}'))
                continue
            if d.status & p.ST_LIMITED:
                limited.append((d.step, p.fault_text(d)))
        why = _usable(d, client, act)
        if why:
            malformed.append((d.step, why))
            continue
        if d.step not in sent:
            out_of_order.append(d.step)
        elif d.step in used:
            duplicate.append(d.step)
        else:
            used[d.step] = d
            latency[d.step] = (t - sent[d.step]) * 1e-6
            if latency[d.step] > LATE_PERIODS * period * 1e3:
                late.append(d.step)
    refused = {k for k, _ in inactive}
    lost = [k for k in range(steps) if k not in used and k not in refused]
    ms = np.array(list(latency.values())) if latency else np.zeros(1)
    silences = _runs(lost)
    longest = max(silences, key=len) if silences else []
    figures = {
        'replies': len(used), 'replies_lost': len(lost), 'replies_late': len(late),
        'replies_malformed': len(malformed), 'replies_duplicate': len(duplicate),
        'replies_out_of_order': len(out_of_order), 'limited': len(limited),
        'latency_ms': {q: round(float(np.percentile(ms, v)), 3)
                       for q, v in (('p50', 50), ('p90', 90), ('p99', 99), ('max', 100))},
        'late_after_ms': round(LATE_PERIODS * period * 1e3, 3),
        'longest_silence_ms': round(len(longest) * period * 1e3, 1),
        'send_late_ms_max': round(max(send_late) * 1e3, 3),
    }
    problems = []
    long_silences = [run for run in silences if len(run) >= SILENCE_STEPS]
    single = [k for k in lost if not any(k in run for run in long_silences)]
    for run in long_silences:
        end = 'to the end of the sequence' if run[-1] == steps - 1 else f'to step {run[-1]}'
        problems.append(f'controller silent for {len(run) * period * 1e3:.0f} ms from step '
                        f'{run[0]} {end} ({len(run)} replies lost)')
    if single:
        why = [f'malformed ({m[1]})' for m in malformed if m[0] in single]
        problems.append(f'replies lost: {len(single)} of {steps} ({pattern(single, steps)})'
                        + (f'; in their place: {", ".join(why[:3])}' if why else ''))
    if inactive:
        problems.append(f'from step {min(refused)} the controller answers not ACTIVE '
                        f'({inactive[0][1]}): {len(refused)} steps')
    if malformed:
        problems.append(f'malformed replies: {len(malformed)} ('
                        + '; '.join(f'step {s}: {w}' for s, w in malformed[:3]) + ')')
    if len(late) > late_tolerance * steps or periodic(late, steps):
        worst = max(latency[k] for k in late)
        problems.append(f'replies late (after {figures["late_after_ms"]:g} ms): {len(late)} of '
                        f'{steps} ({pattern(late, steps)}), worst {worst:.2f} ms')
    if duplicate:
        problems.append(f'duplicate replies: {len(duplicate)} ({pattern(duplicate, steps)})')
    if out_of_order:
        problems.append(f'replies labelled with steps never sent: {pattern(out_of_order)}')
    if limited:
        problems.append(f'commands refused by the controller limits: {len(limited)} '
                        f'(step {limited[0][0]}: {limited[0][1]})')
    if client.version == 2 and len(sequences) > 1:
        jumps = int(np.count_nonzero(np.diff(np.array(sequences, np.int64)) != 1))
        figures['sequence_breaks'] = jumps
    detail = '; '.join(problems) or (
        f'{steps} replies in order, reply time p50 {figures["latency_ms"]["p50"]:.3f} ms, '
        f'p99 {figures["latency_ms"]["p99"]:.3f} ms, max {figures["latency_ms"]["max"]:.3f} ms'
        + (f' ({len(late)} late, within the {late_tolerance:.1%} tolerance, no pattern)'
           if late else ''))
    seq = _entry('sequence', not problems, detail, **figures)
    if sessions or inactive:
        step = inactive[0][0] if inactive else (longest[0] if longest else '?')
        text = (f'controller restarted: new session {sorted(sessions)[0]:#010x}'
                if sessions else 'controller no longer ACTIVE')
        if inactive:
            text += f' (answers from step {inactive[0][0]} not ACTIVE: {inactive[0][1]})'
        if longest:
            text += f', after {len(longest) * period * 1e3:.0f} ms of silence from step ' \
                    f'{longest[0]}'
        restart = _entry('restart', False, text, restart_step=step)
    else:
        restart = _entry('restart', True, f'one session {client.session:#010x}, ACTIVE '
                         'throughout' if client.version == 2 else
                         'version 1: no session; no silence that would mean a restart'
                         if not long_silences else 'version 1 controller went silent')
        if client.version == 1 and long_silences and long_silences[-1][-1] == steps - 1:
            restart = _entry('restart', False, f'silent from step {long_silences[-1][0]} to '
                             'the end: the controller restarted or stopped')
    last = max(sent)
    return seq, restart, last


def _runs(steps):
    runs, run = [], []
    for k in steps:
        if run and k == run[-1] + 1:
            run.append(k)
        else:
            if run:
                runs.append(run)
            run = [k]
    if run:
        runs.append(run)
    return runs


def _reply_to(client, act, step, values):
    """Send COMMAND ``step``; return (usable REPLY or None, why not)."""
    d, ms = client.request(p.COMMAND, step, values, want=p.REPLY)
    if d is None:
        return None, f'no REPLY within {client.timeout_s:g} s', None
    if d.version == 2 and (d.session != client.session or not d.active):
        return None, f'REPLY not ACTIVE ({p.fault_text(d) or "status " + hex(d.status)})', ms
    why = _usable(d, client, act)
    if why or d.step != step:
        return None, why or f'REPLY labelled step {d.step}', ms
    return d, '', ms


def _late_command(client, act, step, fs_hz):
    time.sleep(10.0 / fs_hz)
    d, why, ms = _reply_to(client, act, step, act['position'])
    if d is None:
        return _entry('late_command', False, f'COMMAND {step} sent 10 periods late: {why}')
    return _entry('late_command', True, f'COMMAND {step} sent 10 periods late answered in '
                  f'{ms:.3f} ms', reply_ms=round(ms, 3))


def _duplicate_command(client, act, step):
    first, why, _ = _reply_to(client, act, step, act['position'])
    if first is None:
        return _entry('duplicate_command', False, f'COMMAND {step}: {why}')
    again, why, _ = _reply_to(client, act, step, act['position'])
    if again is None:
        return _entry('duplicate_command', False, f'COMMAND {step} sent again: {why}')
    if not np.array_equal(first.values, again.values):
        return _entry('duplicate_command', False, f'COMMAND {step} sent again was applied '
                      'again: its REPLY has other values (answer it from a cache)')
    after, why, _ = _reply_to(client, act, step + 1, act['position'])
    if after is None:
        return _entry('duplicate_command', False, f'COMMAND {step + 1} after the duplicate: '
                      f'{why}')
    return _entry('duplicate_command', True, f'COMMAND {step} sent twice: the same REPLY '
                  'twice, the next step answered')


def _heartbeat(client):
    d, ms = client.request(p.HEARTBEAT, 0, want=p.HEARTBEAT)
    if d is None:
        return _entry('heartbeat', False, f'no HEARTBEAT answer within {client.timeout_s:g} s')
    if d.session != client.session or not d.active:
        return _entry('heartbeat', False, f'HEARTBEAT answer: session {d.session:#010x}, '
                      f'status {d.status:#x} ({p.fault_text(d) or "not ACTIVE"})')
    return _entry('heartbeat', True, f'answered in {ms:.3f} ms, ACTIVE', reply_ms=round(ms, 3))


def _deactivate(client, act, step):
    ack, ms = client.request(p.DEACTIVATE, 0, want=p.ACK)
    if ack is None:
        return _entry('deactivate', False, f'no ACK to DEACTIVATE within {client.timeout_s:g} s')
    if ack.version == 2 and ack.active:
        return _entry('deactivate', False, 'the ACK to DEACTIVATE still says ACTIVE')
    d, _ = client.request(p.COMMAND, step, act['position'], want=p.REPLY)
    if d is not None and (d.version == 1 or d.active):
        return _entry('deactivate', False, f'COMMAND {step} after DEACTIVATE was answered as '
                      'ACTIVE (it must not be applied)')
    return _entry('deactivate', True, f'acknowledged in {ms:.3f} ms; a COMMAND after it was '
                  'not applied', ack_ms=round(ms, 3))


def report_text(report: dict) -> str:
    """Return the printed report: one line per check, then PASS/FAIL naming the fault."""
    lines = [f"controller-check {report['controller']}: {report['channels']} channel(s) at "
             f"{report['fs_hz']:g} Hz, protocol version {report.get('protocol_version', '?')}"]
    for c in report['checks']:
        lines.append(f"  {'pass' if c['passed'] else 'FAIL'}  {c['name']:<18} {c['detail']}")
    lat = report.get('latency_ms')
    if lat:
        seq = next(c for c in report['checks'] if c['name'] == 'sequence')
        lines.append(f"  reply time [ms]: p50 {lat['p50']:.3f}, p90 {lat['p90']:.3f}, "
                     f"p99 {lat['p99']:.3f}, max {lat['max']:.3f} (late after "
                     f"{seq['late_after_ms']:g} ms; the checker's own send lateness up to "
                     f"{seq['send_late_ms_max']:.3f} ms)")
    lines.append('PASS' if report['passed'] else f"FAIL: {report['fault']}")
    return '\n'.join(lines) + '\n'
