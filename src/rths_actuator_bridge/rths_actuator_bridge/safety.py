"""Safety limits and the supervisor state machine of the actuator bridge.

The bridge enforces these rules whatever the other nodes send (issue 4):

* Command limits, checked on every command before it may reach the plant
  (``fs`` = sampling frequency, ``u_k`` the command of step k, ``p`` the last
  command sent)::

      |u_k| <= stroke_m                                   (seed: +-0.254 m, section 4.3.1)
      |u_k - p_{k-1}| fs <= velocity_m_s
      |u_k - 2 p_{k-1} + p_{k-2}| fs^2 <= acceleration_m_s2
      |u_k| + v_out^2 / (2 acceleration_m_s2) <= stroke_m  (room to brake inside the stroke)

  and ``u_k`` finite.  A violating command is never sent.
* Measurement limits: ``|force| <= force_n`` (seed section 5.1.2: four load
  cells x 2000 N = 8000 N), ``|DTM relative displacement| <= dtm_rel_disp_m``,
  finite readings: up to ``max_invalid_measurements`` non-finite ones in a row
  (e.g. lost UDP replies; the bridge fills them by its gap policy) pass, one
  more trips the supervisor.
* Watchdog: ``watchdog_steps`` consecutive steps without a new command.  While
  fewer steps are missing the supervisor extrapolates the last command at
  constant velocity (zero acceleration; still checked against every limit).
  Cold start: in the first ``start_grace_steps`` steps of the run (realtime:
  ticks since the clock started) misses do not trip it yet; the actuator is at
  rest there (the command extrapolated from rest holds it) and the commands
  are rejoined as below once they come.  A run whose commands have not caught
  up by then trips at that step.  (The processes layout on a 2-core VM: the
  first commands after the clock started came 2-6 ticks late for ~20 ms while
  every process ran its first steps, and the 10-step watchdog tripped at step
  10 in 3 of 4 runs.)
* Stalls of the loop itself (the bridge's clock: its process or the whole host
  stopped, e.g. a virtual-machine stall; in the composed layout every node
  stops with it): :meth:`SafetySupervisor.stalled` with the number of ticks
  that passed without running.  No command was written meanwhile, so nothing
  was extrapolated: the actuator held its last command.  A stall longer than
  ``stall_limit_s`` aborts safely (the watchdog trips: HOLD brakes from the
  last commanded velocity within the acceleration limit, then RAMP and
  STOPPED, as after any fault); a shorter one resumes with the command of the
  next step (in the composed layout the chain stalled with the clock, so the
  commands continue in step order), and if that command breaks the velocity
  or acceleration limit it is rejoined as below (ramped back in at 80 % of the
  limits), never jumped to.  The actuator is never commanded outside its
  limits by a stall of any length (``test_stall.py``: 20, 50 and 200 ms at
  1024 Hz, behind the designed high-pass compensator).  Stalls of the other
  nodes while the clock runs (processes layout) are missing commands: the
  watchdog below.
* Rejoin after missing commands: when commands come back after a miss streak,
  the extrapolated position has drifted from them (a 13-step stall of a
  1 m/s BLWN drifted 4.5 mm: a 4.7 m/s jump).  Only then, a command that
  breaks the velocity or acceleration limit but is finite and inside the
  stroke is not a fault: the supervisor approaches the newest command at
  80 % of the velocity and acceleration limits (like the ramp, every output
  still checked) until the commands pass unchanged for ``REJOIN_SETTLE_STEPS``
  steps in a row (a command that passes while the approach still moves may
  leave a velocity the next command cannot stop: the approach brakes it).  If
  the approach takes
  ``watchdog_steps`` steps it trips (``rejoin: ...``).  A jump without a
  preceding miss still trips at once: it is a bad command, not a stall.
* Instability detector, over windows of ``instability_window_steps`` samples:
  RMS tracking error ``e_k = y_k - p_k`` above ``instability_tracking_m``, or
  the RMS of the force oscillation (force minus its window mean) above
  ``instability_force_n``, or either RMS growing by more than the factor
  ``instability_growth`` for ``instability_growth_windows`` consecutive
  windows (while above a tenth of its threshold): an uncompensated RTHS loop
  with ~15 ms delay (seed section 6.1: 15.64 ms) can go unstable.
* Emergency stop (topic or service of the node) -> :meth:`SafetySupervisor.emergency_stop`.
  The death of the launcher supervising the run is one too, with hold and ramp
  shortened to ``launcher_loss_stop_s`` (:mod:`rths_common.lifeline`).

After any fault: HOLD (brake to standstill at ``acceleration_m_s2``, then keep
the position for ``hold_time_s``), RAMP (move to ``safe_position_m`` within the
velocity and acceleration limits, taking about ``ramp_time_s``), STOPPED (the
owner deactivates the backend).  State numbers are those of
``rths_msgs/LoopStatus``: OK/ACTIVE = 0, HOLD = 1, RAMP = 2, STOPPED = 3, INACTIVE = 4.
"""

from dataclasses import dataclass, fields
import math

import numpy as np

from rths_common.params import LOOP_RATE_RANGE_HZ

#: Commands that must pass unchanged in a row before a rejoin after missing commands ends.
REJOIN_SETTLE_STEPS = 3

ACTIVE = OK = 0
HOLD = 1
RAMP = 2
STOPPED = 3
INACTIVE = 4
STATE_NAMES = {ACTIVE: 'ACTIVE', HOLD: 'HOLD', RAMP: 'RAMP', STOPPED: 'STOPPED',
               INACTIVE: 'INACTIVE'}

#: Safety parameters: key -> (default, meaning with unit).
SAFETY_PARAMS = {
    'fs_hz': (1024.0, '[Hz] loop sampling frequency'),
    'stroke_m': (0.254, '[m] actuator stroke +- (seed: +-10 in = +-0.254 m)'),
    'velocity_m_s': (1.0, '[m/s] largest command velocity'),
    'acceleration_m_s2': (100.0, '[m/s^2] largest command acceleration'),
    'force_n': (8000.0, '[N] largest measured force (seed: 4 load cells x 2000 N)'),
    'dtm_rel_disp_m': (0.1, '[m] DTM relative-displacement safe range +-'),
    'safe_position_m': (0.0, '[m] position the actuator ramps to after a fault'),
    'ramp_time_s': (2.0, '[s] nominal duration of the ramp to the safe position'),
    'hold_time_s': (0.25, '[s] time the position is held before ramping'),
    'launcher_loss_stop_s': (0.3, '[s] hold + ramp of the safe stop when the launcher '
                             'supervising the run dies (its processes must be gone within 1 s)'),
    'watchdog_steps': (10, '[steps] missing commands in a row that trip the watchdog'),
    'start_grace_steps': (128, '[steps] first steps of a run in which missing commands do not '
                          'trip the watchdog yet (the loop\'s cold start; 0: none)'),
    'stall_limit_s': (0.5, '[s] longest stall of the loop itself (its clock) that resumes; a '
                      'longer one trips the watchdog'),
    'max_invalid_measurements': (3, '[steps] non-finite/lost measurements in a row that the '
                                 'gap policy fills; one more trips'),
    'instability_window_steps': (256, '[steps] window of the instability detector'),
    'instability_tracking_m': (0.02, '[m] RMS tracking error (measured - command) that aborts'),
    'instability_force_n': (3000.0, '[N] RMS force oscillation that aborts'),
    'instability_growth': (1.5, '[-] window-to-window RMS growth factor counted as growing'),
    'instability_growth_windows': (4, '[windows] consecutive growing windows that abort'),
}
#: Ranges of the limits (inclusive; ints: integer parameters): beyond them a value is
#: almost surely in the wrong unit or a typo.  The checks below add > 0 and the stroke.
SAFETY_RANGES = {
    'fs_hz': LOOP_RATE_RANGE_HZ,
    'stroke_m': (0.0, 1.0),
    'velocity_m_s': (0.0, 10.0),
    'acceleration_m_s2': (0.0, 100_000.0),
    'force_n': (0.0, 1.0e7),
    'dtm_rel_disp_m': (0.0, 1.0),
    'safe_position_m': (-1.0, 1.0),
    'ramp_time_s': (0.0, 600.0),
    'hold_time_s': (0.0, 600.0),
    'launcher_loss_stop_s': (0.0, 600.0),
    'watchdog_steps': (1, 1_000_000),
    'start_grace_steps': (0, 1_000_000),
    'stall_limit_s': (0.0, 600.0),
    'max_invalid_measurements': (1, 1_000_000),
    'instability_window_steps': (2, 10_000_000),
    'instability_tracking_m': (0.0, 1.0),
    'instability_force_n': (0.0, 1.0e7),
    'instability_growth': (1.0, 1000.0),
    'instability_growth_windows': (1, 10_000),
}
#: Limits that may differ per actuator: a list of one value per channel (the bridge's
#: ``n_channels``) instead of one number for all (a multi-actuator rig, docs/multi_actuator.md).
PER_CHANNEL = ('stroke_m', 'velocity_m_s', 'acceleration_m_s2', 'force_n', 'dtm_rel_disp_m',
               'safe_position_m', 'instability_tracking_m', 'instability_force_n')
_INT_KEYS = {'watchdog_steps', 'start_grace_steps', 'max_invalid_measurements',
             'instability_window_steps', 'instability_growth_windows'}


@dataclass(frozen=True)
class SafetyLimits:
    """Limits the bridge enforces (SI units; meanings in :data:`SAFETY_PARAMS`).

    A :data:`PER_CHANNEL` limit is a number (every channel) or a tuple of one number per
    channel; :meth:`channel_count` says how many channels the tuples are for.
    """

    fs_hz: float = 1024.0
    stroke_m: float = 0.254
    velocity_m_s: float = 1.0
    acceleration_m_s2: float = 100.0
    force_n: float = 8000.0
    dtm_rel_disp_m: float = 0.1
    safe_position_m: float = 0.0
    ramp_time_s: float = 2.0
    hold_time_s: float = 0.25
    launcher_loss_stop_s: float = 0.3
    watchdog_steps: int = 10
    start_grace_steps: int = 128
    stall_limit_s: float = 0.5
    max_invalid_measurements: int = 3
    instability_window_steps: int = 256
    instability_tracking_m: float = 0.02
    instability_force_n: float = 3000.0
    instability_growth: float = 1.5
    instability_growth_windows: int = 4

    @classmethod
    def from_params(cls, params: dict) -> 'SafetyLimits':
        """Build from flat parameters (missing keys take defaults); ValueError names bad keys."""
        values = {}
        for f in fields(cls):
            default, meaning = SAFETY_PARAMS[f.name]
            raw = params.get(f.name, default)
            if f.name in PER_CHANNEL and isinstance(raw, (list, tuple, np.ndarray)):
                if len(raw) == 0:
                    raise ValueError(f'safety parameter {f.name!r} is an empty list; give one '
                                     f'number, or one per actuator channel ({meaning})')
                vals = tuple(_limit_value(f'{f.name}[{i}]', r, meaning)
                             for i, r in enumerate(raw))
                values[f.name] = vals[0] if len(vals) == 1 else vals
            else:
                values[f.name] = _limit_value(f.name, raw, meaning)
        lim = cls(**values)
        lengths = {key: len(getattr(lim, key)) for key in PER_CHANNEL
                   if isinstance(getattr(lim, key), tuple)}
        if len(set(lengths.values())) > 1:
            raise ValueError('safety parameters ' + ', '.join(
                f'{k!r} ({n} values)' for k, n in lengths.items())
                + ' list different numbers of actuator channels; give each one value per '
                'channel (or one number for all)')
        safe, stroke = np.asarray(lim.safe_position_m), np.asarray(lim.stroke_m)
        if np.any(np.abs(safe) > stroke):
            raise ValueError(f"safety parameter 'safe_position_m' = {lim.safe_position_m} m is "
                             f'outside the stroke +-{lim.stroke_m} m; choose a position inside it')
        if lim.instability_growth <= 1:
            raise ValueError("safety parameter 'instability_growth' must be > 1 (e.g. 1.5)")
        return lim

    def channel_count(self):
        """Return the channels the per-channel limits list (None: every limit is one number)."""
        for key in PER_CHANNEL:
            value = getattr(self, key)
            if isinstance(value, tuple):
                return len(value)
        return None

    def per_channel(self, n: int) -> dict:
        """Return every :data:`PER_CHANNEL` limit as an array of ``n`` values.

        ValueError naming the limit when it lists another number of channels.
        """
        count = self.channel_count()
        if count is not None and count != n:
            key = next(k for k in PER_CHANNEL if isinstance(getattr(self, k), tuple))
            raise ValueError(f'safety parameter {key!r} lists {count} values but the actuator '
                             f'has {n} channel(s); give one value per channel')
        return {key: np.broadcast_to(np.asarray(getattr(self, key), float), (n,)).copy()
                for key in PER_CHANNEL}


def _limit_value(name: str, raw, meaning: str):
    """Return one limit's value checked (finite, > 0 or integer as its kind); ValueError."""
    key = name.split('[')[0]
    try:
        val = float(raw)
    except (TypeError, ValueError):
        raise ValueError(f'safety parameter {name!r} = {raw!r} is not a number; '
                         f'set it to {meaning}') from None
    if not math.isfinite(val):
        raise ValueError(f'safety parameter {name!r} = {raw!r} must be finite ({meaning})')
    if key in _INT_KEYS:
        low = 0 if key == 'start_grace_steps' else 1
        if val != int(val) or val < low:
            raise ValueError(f'safety parameter {name!r} = {raw!r} must be an integer '
                             f'>= {low} ({meaning})')
        return int(val)
    if key != 'safe_position_m' and val <= 0:
        raise ValueError(f'safety parameter {name!r} = {raw!r} must be > 0 ({meaning})')
    return val


class SafetySupervisor:
    """State machine INACTIVE -> ACTIVE -> HOLD -> RAMP -> STOPPED guarding one or more channels.

    Call :meth:`filter` once per loop step with the new command (or None), write
    what it returns (unless None), then call :meth:`check_measurement` with the
    reading of that step.
    """

    def __init__(self, limits: SafetyLimits = None):
        """Create an INACTIVE supervisor with ``limits`` (default :class:`SafetyLimits`)."""
        self.limits = limits or SafetyLimits()
        self.state = INACTIVE
        self.fault = ''
        self.faults = []
        self.configured = False
        self.n = 1
        #: Extra checks of a multi-actuator rig's interface (set by the bridge): a command
        #: ``u -> fault text or ''`` and a reading ``(displacement, force) -> fault text or ''``.
        self.command_check = None
        self.measurement_check = None
        self._reset_motion(np.zeros(1))
        self._precompute()

    def _precompute(self):
        """Constants of the one-channel fast path of :meth:`filter` / :meth:`check_measurement`.

        Each bound is the one :meth:`check_command` and :meth:`check_measurement`
        compare against (same floating-point expression), so the fast path accepts
        exactly what the general path accepts.
        """
        lim = self.limits
        tol = 1e-9
        self._fs = lim.fs_hz
        count = lim.channel_count()
        self.ch = lim.per_channel(count if count is not None else self.n)
        if count is not None:      # per-channel limits: no one-channel fast path
            self._stroke_tol = self._vel_tol = self._acc_tol = self._two_acc = math.nan
            return
        self._stroke_tol = lim.stroke_m * (1 + tol)
        self._vel_tol = lim.velocity_m_s * (1 + tol)
        self._acc_tol = lim.acceleration_m_s2 * (1 + tol)
        self._two_acc = 2 * lim.acceleration_m_s2

    # ------------------------------------------------------------ lifecycle
    def configure(self, limits: SafetyLimits = None):
        """Accept (new) limits; stays INACTIVE."""
        if limits is not None:
            self.limits = limits
        self._precompute()
        self.configured = True
        self.state = INACTIVE
        self.fault = ''
        self.faults = []

    def activate(self, position=0.0):
        """Arm at the current actuator ``position`` [m] (at rest); state ACTIVE."""
        if not self.configured:
            self.configure()
        pos = np.atleast_1d(np.asarray(position, float)).copy()
        self.n = pos.size
        self.ch = self.limits.per_channel(self.n)
        if not np.all(np.isfinite(pos)) or np.any(np.abs(pos) > self.ch['stroke_m']):
            raise ValueError(f'cannot activate: actuator position {pos} m is not finite or '
                             f'outside the stroke +-{self.limits.stroke_m} m')
        self._reset_motion(pos)
        self.state = ACTIVE
        self.fault = ''
        self.faults = []

    def deactivate(self):
        """Back to INACTIVE: nothing is sent any more."""
        self.state = INACTIVE

    def _reset_motion(self, pos):
        self.pos = pos.copy()              # last command sent
        self.vel = np.zeros_like(pos)      # its velocity [m/s]
        self.missing = 0
        self.rejoin_left = 0               # steps left to rejoin the commands after misses
        self.rejoins = 0                   # rejoins so far (one per miss streak that needed it)
        self.rejoin_clean = 0              # commands passed unchanged in a row while rejoining
        self.invalid = 0
        self.hold_left = 0
        self.within_s = None               # a stop's time budget (emergency_stop), if any
        self._win_e, self._win_f = [], []
        self._rms_prev = {'tracking': None, 'force': None}
        self._growing = {'tracking': 0, 'force': 0}
        self.last_sent = None

    # ------------------------------------------------------------ faults
    def trip(self, text: str):
        """Record the fault ``text`` (e.g. one the backend reports): HOLD, RAMP, STOPPED."""
        if text not in self.faults:
            self._trip(text)

    def finish(self):
        """End of a run without a fault: brake, then ramp to the safe position and stop."""
        if self.state == ACTIVE:
            self.state = HOLD
            self.hold_left = 1

    def _trip(self, text: str):
        """Record a fault; from ACTIVE go to HOLD (braking)."""
        self.faults.append(text)
        if not self.fault:
            self.fault = text
        if self.state == ACTIVE:
            self.state = HOLD
            self.hold_left = max(1, int(round(self._hold_s() * self.limits.fs_hz)))

    def _hold_s(self) -> float:
        """Hold time [s]: ``hold_time_s``, at most a quarter of a stop's ``within_s``."""
        hold = self.limits.hold_time_s
        return hold if self.within_s is None else min(hold, 0.25 * self.within_s)

    def _ramp_s(self) -> float:
        """Nominal ramp time [s]: ``ramp_time_s``, at most the rest of a stop's ``within_s``."""
        ramp = self.limits.ramp_time_s
        if self.within_s is None:
            return ramp
        return max(1e-6, min(ramp, self.within_s - self._hold_s()))

    def emergency_stop(self, reason: str = '', within_s: float | None = None):
        """Stop the run now: HOLD, RAMP to the safe position, STOPPED.

        ``within_s``: hold and ramp are shortened to take about that long together
        (the ramp still within the velocity and acceleration limits, so a long way
        to the safe position takes longer); also a stop already under way.
        """
        text = f'emergency stop: {reason}' if reason else 'emergency stop'
        if within_s is not None:
            self.within_s = float(within_s)
            self.hold_left = min(self.hold_left,
                                 max(1, int(round(self._hold_s() * self.limits.fs_hz))))
        if self.state == INACTIVE:
            self.faults.append(text)
            self.fault = self.fault or text
            self.state = STOPPED
            return
        self._trip(text)

    def stalled(self, steps: int, step: int) -> str:
        """Apply the stall policy: ``steps`` ticks passed unrun before ``step`` (module doc).

        Longer than ``stall_limit_s``: trip the watchdog (HOLD, RAMP, STOPPED).
        Shorter: the next command rejoins within 80 % of the limits if it jumps
        (as after missing commands).  Returns the fault text ('' if none).  Only
        an ACTIVE supervisor is affected.
        """
        if self.state != ACTIVE or steps <= 0:
            return ''
        lim = self.limits
        stalled_s = int(steps) / lim.fs_hz
        if stalled_s > lim.stall_limit_s:
            self._trip(f'watchdog: the loop stalled for {int(steps)} steps ({stalled_s:.3f} s > '
                       f'stall_limit_s {lim.stall_limit_s:g} s) before step {step}')
            return self.fault
        self.missing = max(self.missing, 1)   # the next command may rejoin instead of jumping
        return ''

    # ------------------------------------------------------------ commands
    def check_command(self, command) -> str:
        """Return '' if ``command`` may be sent after the last one, else the fault text."""
        lim = self.limits
        u = np.atleast_1d(np.asarray(command, float))
        if u.shape != self.pos.shape:
            return f'command size {u.size} != {self.pos.size} actuator channel(s)'
        fs = lim.fs_hz
        tol = 1e-9
        strokes, vels, accs = self.ch['stroke_m'], self.ch['velocity_m_s'], \
            self.ch['acceleration_m_s2']
        for i, ui in enumerate(u):
            ch = f' (channel {i})' if u.size > 1 else ''
            stroke, vel, acc = float(strokes[i]), float(vels[i]), float(accs[i])
            if not math.isfinite(ui):
                return f'non-finite command {ui}{ch}'
            if abs(ui) > stroke * (1 + tol):
                return f'stroke limit: command {ui:.6g} m > {stroke:.6g} m{ch}'
            v = (ui - self.pos[i]) * fs
            if abs(v) > vel * (1 + tol):
                return (f'velocity limit: command velocity {v:.6g} m/s > '
                        f'{vel:.6g} m/s{ch}')
            a = (v - self.vel[i]) * fs
            if abs(a) > acc * (1 + tol):
                return (f'acceleration limit: command acceleration {a:.6g} m/s^2 > '
                        f'{acc:.6g} m/s^2{ch}')
            if v * ui > 0:
                reach = abs(ui) + v * v / (2 * acc)
                if reach > stroke * (1 + tol):
                    return (f'stroke limit: command {ui:.6g} m at {v:.6g} m/s cannot brake '
                            f'before {stroke:.6g} m (would reach {reach:.6g} m){ch}')
        if self.command_check is not None:
            return self.command_check(u)
        return ''

    def _accept(self, u):
        u = np.asarray(u, float)
        fs = self.limits.fs_hz
        self.vel = (u - self.pos) * fs
        self.pos = u.copy()
        self.last_sent = u.copy()
        return u.copy()

    def _brake(self):
        """One step of maximum deceleration towards standstill."""
        dv = self.ch['acceleration_m_s2'] / self.limits.fs_hz
        vel = np.sign(self.vel) * np.maximum(np.abs(self.vel) - dv, 0.0)
        return self._accept(self.pos + vel / self.limits.fs_hz)

    def _approach(self, target, v_cap, acc):
        """Next position towards ``target`` at speed <= ``v_cap``, acceleration <= ``acc``.

        The speed stays on the discrete braking curve, so a fixed target is reached without
        passing it (a safe position at the stroke end stays inside the stroke).  Braking by
        ``dv = acc / fs`` per step, the speeds ``v, v - dv, ..., v - m dv`` (``m = floor(v /
        dv)``) cover ``D(v) = ((m + 1) v - m (m + 1) dv / 2) / fs``; the speed is the largest
        with ``D(v) <= e``, ``e`` the distance to the target: with ``E = e fs / dv`` and
        ``m = floor((sqrt(1 + 8 E) - 1) / 2)``, ``v = dv (E / (m + 1) + m / 2)``.  (The
        continuous curve ``sqrt(2 acc e)`` overshot by up to ``0.6 acc / fs^2``, 61 um at
        100 m/s^2 and 1024 Hz.)
        """
        fs = self.limits.fs_hz
        err = target - self.pos
        dv = acc / fs
        e_steps = np.abs(err) * fs / dv
        m = np.floor(0.5 * (np.sqrt(1.0 + 8.0 * e_steps) - 1.0))
        v_brake = dv * (e_steps / (m + 1.0) + 0.5 * m)
        v_des = np.sign(err) * np.minimum(v_cap, v_brake)
        step = np.clip(v_des - self.vel, -dv, dv)
        return self.pos + (self.vel + step) / fs

    def _ramp(self):
        """One step towards the safe position within velocity/acceleration limits."""
        ch = self.ch
        v_cap = np.minimum(ch['velocity_m_s'],
                           np.maximum(np.abs(self._ramp_dist) / self._ramp_s(), 1e-6))
        return self._accept(self._approach(ch['safe_position_m'], v_cap,
                                           ch['acceleration_m_s2']))

    def filter(self, step: int, command=None):
        """Return ``(command_to_send or None, state, fault_text)`` for loop step ``step``.

        ``command`` None means no new command arrived this step (watchdog
        counting).  The returned command always respects every command limit.
        """
        if self.state == ACTIVE and self.n == 1 and command is not None:
            out = self._filter_one(command)
            if out is not None:
                return out, ACTIVE, ''
        lim = self.limits
        if self.state == INACTIVE:
            return None, INACTIVE, self.fault or 'not active'
        if self.state == ACTIVE:
            if command is None:
                self.missing += 1
                if self.missing >= lim.watchdog_steps and step >= lim.start_grace_steps:
                    self._trip(f'watchdog: no command for {self.missing} steps '
                               f'(limit {lim.watchdog_steps}) at step {step}')
                else:
                    guess = self.pos + self.vel / lim.fs_hz
                    text = self.check_command(guess)
                    if not text:
                        return self._accept(guess), ACTIVE, ''
                    self._trip(f'{text} (extrapolating a missing command)')
            else:
                rejoining = self.missing > 0 or self.rejoin_left > 0
                self.missing = 0
                text = self.check_command(command)
                if not text:
                    if self.rejoin_left:
                        self.rejoin_clean += 1
                        if self.rejoin_clean >= REJOIN_SETTLE_STEPS:
                            self.rejoin_left = 0      # rejoined
                    return self._accept(np.atleast_1d(np.asarray(command, float))), ACTIVE, ''
                if rejoining and self._rejoinable(command):
                    out, text = self._rejoin(command)
                    if out is not None:
                        return out, ACTIVE, ''
                self._trip(f'{text} at step {step}')
        if self.state == HOLD:
            if np.any(self.vel != 0):
                out = self._brake()
            else:
                self.hold_left -= 1
                out = self._accept(self.pos)
                if self.hold_left <= 0:
                    self.state = RAMP
                    self._ramp_dist = self.ch['safe_position_m'] - self.pos
            return out, HOLD, self.fault
        if self.state == RAMP:
            out = self._ramp()
            at_safe = np.all(np.abs(self.pos - self.ch['safe_position_m']) < 1e-9)
            if at_safe and np.all(self.vel == 0):
                self.state = STOPPED
                return out, STOPPED, self.fault
            if at_safe:
                self.vel[:] = 0.0
            return out, RAMP, self.fault
        # STOPPED: keep the safe position (the owner deactivates the backend)
        return self._accept(self.pos) if self.last_sent is not None else None, STOPPED, self.fault

    def _rejoinable(self, command) -> bool:
        """Return True for a command to approach after misses: right size, finite, in the stroke."""
        u = np.atleast_1d(np.asarray(command, float))
        return (u.shape == self.pos.shape and bool(np.all(np.isfinite(u)))
                and bool(np.all(np.abs(u) <= self.ch['stroke_m'])))

    def _rejoin(self, command):
        """Step towards ``command`` at 80 % of the limits: ``(output, '')`` or ``(None, fault)``."""
        lim = self.limits
        if self.rejoin_left == 0:
            self.rejoin_left = lim.watchdog_steps
            self.rejoins += 1
        self.rejoin_left -= 1
        self.rejoin_clean = 0
        if self.rejoin_left == 0:
            return None, (f'rejoin: the commands were not reached within {lim.watchdog_steps} '
                          'steps after missing commands')
        out = self._approach(np.atleast_1d(np.asarray(command, float)),
                             0.8 * self.ch['velocity_m_s'], 0.8 * self.ch['acceleration_m_s2'])
        text = self.check_command(out)
        if text:
            return None, f'{text} (rejoining the commands after missing ones)'
        return self._accept(out), ''

    def _filter_one(self, command):
        """Fast path of :meth:`filter`: one channel, ACTIVE, a command that passes every limit.

        Plain floats instead of numpy on 1-element arrays; the arithmetic is that
        of :meth:`check_command` and :meth:`_accept`, so the result is identical.
        Returns the command to send, or None when the general path must decide
        (any limit violated, another command type or size, rejoining after misses).
        """
        if self.rejoin_left:
            return None
        kind = type(command)
        if kind is list or kind is tuple:
            if len(command) != 1:
                return None
            ui = command[0]
        elif kind is float:
            ui = command
        else:
            return None
        if type(ui) is not float:
            if type(ui) is not int and not isinstance(ui, np.floating):
                return None
            ui = float(ui)
        if not math.isfinite(ui) or abs(ui) > self._stroke_tol:
            return None
        fs = self._fs
        pos, vel = self.pos, self.vel
        v = (ui - pos.item(0)) * fs
        if abs(v) > self._vel_tol:
            return None
        if abs((v - vel.item(0)) * fs) > self._acc_tol:
            return None
        if v * ui > 0 and abs(ui) + v * v / self._two_acc > self._stroke_tol:
            return None
        self.missing = 0
        pos[0] = ui                      # pos and vel are owned by the supervisor
        vel[0] = v
        if self.last_sent is None:
            self.last_sent = np.array((ui,))
        else:
            self.last_sent[0] = ui
        return np.array((ui,))

    # ------------------------------------------------------------ measurements
    def check_measurement(self, displacement, force, rel_disp=None,
                          lost: str = 'measurement lost: non-finite readings') -> str:
        """Check one step's readings; trip on force/DTM range/instability; return fault text.

        ``lost`` names what more than ``max_invalid_measurements`` non-finite
        readings in a row mean (the UDP backend: a controller stall).
        """
        if self.state == INACTIVE:
            return ''
        lim = self.limits
        y = np.atleast_1d(np.asarray(displacement, float))
        f = np.atleast_1d(np.asarray(force, float))
        r = None if rel_disp is None else np.atleast_1d(np.asarray(rel_disp, float))
        text = ''
        if not (np.all(np.isfinite(y)) and np.all(np.isfinite(f))):
            self.invalid += 1
            if self.invalid > lim.max_invalid_measurements:
                text = (f'{lost}: {self.invalid} in a row (more than max_invalid_measurements '
                        f'{lim.max_invalid_measurements})')
        else:
            self.invalid = 0
            force_n = _match(self.ch['force_n'], f.size)
            dtm = None if r is None else _match(self.ch['dtm_rel_disp_m'], r.size)
            if np.any(np.abs(f) > force_n):
                i = int(np.argmax(np.abs(f) / force_n))
                ch = f' (channel {i})' if f.size > 1 else ''
                text = f'force limit: measured force {f[i]:.6g} N > {force_n[i]:.6g} N{ch}'
            elif r is not None and np.any(np.abs(r) > dtm):
                i = int(np.argmax(np.abs(r) / dtm))
                ch = f' (channel {i})' if r.size > 1 else ''
                text = (f'DTM relative displacement limit: {r[i]:.6g} m > '
                        f'{dtm[i]:.6g} m{ch}')
            elif self.measurement_check is not None and (rig := self.measurement_check(y, f)):
                text = rig
            elif self.state == ACTIVE and self.last_sent is not None:
                text = self._instability(y - self.last_sent, f)
        if text and text not in self.faults:
            self._trip(text)
        return text

    def check_measurement_one(self, displacement: float, force: float, rel_disp=None) -> str:
        """:meth:`check_measurement` of one channel given as plain floats (the bridge's fast path).

        The usual case (finite readings inside the limits) is decided with
        floats; everything else goes through :meth:`check_measurement`, so the
        outcome is the same.
        """
        lim = self.limits
        if (self.n != 1 or self.state == INACTIVE or not math.isfinite(displacement)
                or not math.isfinite(force) or abs(force) > lim.force_n
                or (rel_disp is not None and abs(rel_disp) > lim.dtm_rel_disp_m)):
            return self.check_measurement(displacement, force, rel_disp)
        self.invalid = 0
        text = ''
        if self.state == ACTIVE and self.last_sent is not None:
            text = self._instability(displacement - self.last_sent.item(0), force)
        if text and text not in self.faults:
            self._trip(text)
        return text

    def _instability(self, err, force) -> str:
        lim = self.limits
        # one channel: windows of floats (the fast path appends floats too)
        if np.size(err) == 1 and np.size(force) == 1:
            err, force = float(np.ravel(err)[0]), float(np.ravel(force)[0])
        self._win_e.append(err)
        self._win_f.append(force)
        if len(self._win_e) < lim.instability_window_steps:
            return ''
        e = np.array(self._win_e, dtype=float).reshape(len(self._win_e), -1)
        f = np.array(self._win_f, dtype=float).reshape(len(self._win_f), -1)
        self._win_e, self._win_f = [], []
        # per channel: RMS over the window against that channel's threshold
        rms = {'tracking': np.sqrt(np.mean(e ** 2, axis=0)),
               'force': np.sqrt(np.mean((f - f.mean(axis=0)) ** 2, axis=0))}
        thresholds = {'tracking': (self.ch['instability_tracking_m'], 'm'),
                      'force': (self.ch['instability_force_n'], 'N')}
        for key, (thr, unit) in thresholds.items():
            label = 'tracking error' if key == 'tracking' else 'force oscillation'
            value = rms[key]
            thr = _match(thr, value.size)
            i = int(np.argmax(value / thr))
            ch = f' (channel {i})' if value.size > 1 else ''
            if value[i] > thr[i]:
                return (f'instability: RMS {label} {value[i]:.6g} {unit} > {thr[i]:.6g} {unit} '
                        f'over {lim.instability_window_steps} steps{ch}')
            prev = self._rms_prev[key]
            if prev is not None and np.any((value > lim.instability_growth * prev)
                                           & (value > 0.1 * thr)):
                self._growing[key] += 1
            else:
                self._growing[key] = 0
            self._rms_prev[key] = value
            if self._growing[key] >= lim.instability_growth_windows:
                return (f'instability: RMS {label} grew by > x{lim.instability_growth:g} for '
                        f'{self._growing[key]} windows in a row (now {np.max(value):.6g} '
                        f'{unit})')
        return ''


def _match(limit: np.ndarray, size: int) -> np.ndarray:
    """Return the per-channel ``limit`` for readings of ``size`` values (the tightest if other)."""
    return limit if limit.size == size else np.full(size, float(np.min(limit)))
