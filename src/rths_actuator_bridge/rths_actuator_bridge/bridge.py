"""The bridge logic without ROS: a backend guarded by a safety supervisor, one call per step.

The ROS node is a thin shell over :class:`Bridge`: on configure it calls
:meth:`Bridge.configure`, on activate :meth:`Bridge.activate`, per loop step
:meth:`Bridge.step` (with the step's command, or None when none arrived in
time), and on the emergency-stop topic/service :meth:`Bridge.emergency_stop`.
``Bridge.step(k, command) -> StepResult`` is the loop cores' step contract
(:mod:`rths_common.stepping`); its missing-input policy is the safety
supervisor's: a missing command (None) is extrapolated at constant velocity
within every limit, ``watchdog_steps`` misses in a row trip hold -> ramp -> stop.
Lifecycle: nothing is written to the backend before configure + activate;
when the supervisor reaches STOPPED the backend is deactivated.

Missing measurements (an external controller's reply lost, late or malformed:
the backend reads NaN): the gap policy holds the last valid reading (before
the first one: the command as displacement, zero force) and marks the step
``filled``; up to ``max_invalid_measurements`` in a row pass, one more trips
the supervisor (``controller stall``).  A fault the backend reports (the
controller restarted, went inactive or reports its own fault) trips it too.
An external actuator outlives the run: :meth:`Bridge.park` ends every run
that moved it with a ramp to the safe position, then deactivates it.

Command delay line (``command_delay_steps`` = D, default 0): the command of
step k is written at tick k + D, not k.  The node hands every arriving command
to :meth:`Bridge.receive` and asks :meth:`Bridge.due` for the command of each
tick.  This is a jitter buffer for a network between the compensator and the
actuator: the loop's round trip (measurement k out, command k + 1 back) may
then take D + 1 periods instead of one.  The loop sees the D steps as a pure
delay of the plant, ``P(z) z^-D``; an identification run made with the same
D identifies it, and the compensator designed on that plant compensates it
(``rths bench distributed --absorb``).  Ticks before step 0's command is due
write the command of step 0 (the position at rest).

Several actuators (``rig_file``, :mod:`rths_common.rig`, docs/multi_actuator.md): the
file names the actuators (one command channel, displacement sensor and load cell each,
in channel order), their own limits (every :data:`.safety.PER_CHANNEL` limit per
actuator), the coupler and the interface limits.  Commands, displacements and forces stay
per actuator (strokes [m], axial forces [N]); the bridge checks every command's
interface pose ``(x, theta)`` and every reading's pose, force and moment against the
interface limits, and adds them to each step's channels (``interface_disp`` = (x [m],
theta [rad]), ``interface_force`` = (F [N], M [N m])) through :class:`rths_common.rig.Rig`,
the one place strokes and interface DOFs meet.  The backend must drive as many channels
as the file lists actuators (``simulated_rig``; ``udp`` with ``n_channels`` set from the
file); a one-actuator run (no ``rig_file``) is unchanged.
"""

import math
import time

import numpy as np

from rths_common import stepping
from rths_common.params import node_schema, renamed
from rths_common.registry import Registry
from rths_common.rig import load_rig

from . import safety
from .backend import Backend
from .genericclient import GenericClientBackend
from .ideal import IdealBackend
from .marths_rig import SimulatedRigBackend
from .simulated import SimulatedBackend
from .udp import UdpBackend

#: Backend name (the ``backend`` parameter) -> class (a :class:`.backend.Backend`, which
#: carries its summary, parameters, ranges and choices).
BACKENDS = Registry('bridge backend', 'backend',
                    {'simulated': SimulatedBackend, 'udp': UdpBackend, 'ideal': IdealBackend,
                     'genericclient': GenericClientBackend,
                     'simulated_rig': SimulatedRigBackend})
#: The backend of a params file that names none.
DEFAULT_BACKEND = 'simulated'

#: The bridge's own parameters: key -> (default, meaning [unit]).  The backends' are their
#: classes' ``params`` (``simulated.SIM_PARAMS``, ``udp.UDP_PARAMS``), the limits
#: ``safety.SAFETY_PARAMS``.
PARAMS = {
    'backend': (DEFAULT_BACKEND, 'what the bridge drives (rths_actuator_bridge.bridge.BACKENDS)'),
    'command_delay_steps': (0, '[steps] the command of step k is written at tick k + D'),
    'rig_file': ('', "multi-actuator rig file (actuators, coupler, interface limits; "
                 "config/rig_two_actuators.yaml); '' = one actuator"),
}


def backend_class(params: dict, where: str = "parameter 'backend'"):
    """Return the class of the backend ``params`` name (ValueError listing the backends)."""
    return BACKENDS.entry(params.get('backend', DEFAULT_BACKEND), where)


def param_schema(node_params) -> dict:
    """Return the bridge node's parameter schema: its ``node_params``, the core's, the backends'."""
    params, ranges, choices = {}, {}, {'backend': BACKENDS.names()}
    for cls in reversed(list(BACKENDS.values())):
        params.update(cls.params)
        ranges.update(cls.ranges)
        choices.update(cls.choices)
    ranges.update(safety.SAFETY_RANGES, command_delay_steps=(0, MAX_DELAY_STEPS))
    return node_schema(node_params, {**params, **safety.SAFETY_PARAMS, **PARAMS}, ranges,
                       choices, per_channel=safety.PER_CHANNEL)


#: Plausibility bounds of the limits [SI]: a larger value is almost surely in the wrong unit
#: (inches or mm for metres, kN for N is the other way round and passes).
PLAUSIBLE_MAX = {'stroke_m': (1.0, 'm', 'inches or mm'),
                 'velocity_m_s': (10.0, 'm/s', 'mm/s or in/s'),
                 'dtm_rel_disp_m': (1.0, 'm', 'inches or mm'),
                 'safe_position_m': (1.0, 'm', 'inches or mm')}


def check_core_params(core: dict, node_keys=()) -> dict:
    """Validate the bridge core's flat parameters (node-level keys removed); return them.

    Unknown keys (typos; ``node_keys`` are listed as known in the message), an
    unknown backend, non-finite or out-of-unit limits raise ValueError naming
    the field and the fix.
    """
    core = renamed(core, 'dtm', 'specimen', 'bridge parameters')
    backend = core.get('backend', DEFAULT_BACKEND)
    known = {*PARAMS, *safety.SAFETY_PARAMS, *backend_class(core).params}
    unknown = sorted(set(core) - known)
    if unknown:
        raise ValueError(f'unknown parameter(s) {", ".join(unknown)} for backend {backend!r}; '
                         f'known: {", ".join(sorted(known | set(node_keys)))}')
    rig = read_rig(core.get('rig_file', ''))
    safety.SafetyLimits.from_params(rig.bridge_params(core) if rig else core)
    DelayLine(core.get('command_delay_steps', 0))
    for key, (bound, unit, other) in PLAUSIBLE_MAX.items():
        given = core.get(key)
        for value in (given if isinstance(given, (list, tuple)) else [given]):
            if not isinstance(value, (int, float)) or abs(value) <= bound:
                continue
            raise ValueError(f'parameter {key} = {value} {unit} is beyond any lab actuator '
                             f'(> {bound:g} {unit}): it looks like {other}; give it in {unit}')
    return core


def read_rig(path):
    """Return the :class:`rths_common.rig.Rig` of ``rig_file`` ``path`` (None for '')."""
    if not path:
        return None
    if not isinstance(path, str):
        raise ValueError(f'parameter rig_file = {path!r} must be the path of a rig file')
    try:
        return load_rig(path)
    except OSError as err:
        raise ValueError(f'parameter rig_file: {err}; give the path of a rig file '
                         '(config/rig_two_actuators.yaml)') from None


def make_backend(params: dict) -> Backend:
    """Create and configure the backend named by ``params['backend']`` (default 'simulated')."""
    backend = backend_class(params)()
    backend.configure(params)
    return backend


class StepResult(stepping.StepResult):
    """What one bridge step did: ``arrays`` = (applied, displacement, force) of Measurement.

    ``applied`` [m]: the command written (after safety), empty if none;
    ``displacement`` [m] and ``force`` [N]: measured (NaN if nothing was written).
    """

    __slots__ = ()

    def __init__(self, step: int, applied, displacement, force, state: int, fault: str = '',
                 channels=None, filled: int = 0):
        super().__init__(step, (applied, displacement, force), filled, state, fault, False,
                         channels)

    @property
    def applied(self) -> np.ndarray:
        """Return the command written [m] (after safety), empty if none."""
        return self.arrays[0]

    @property
    def displacement(self) -> np.ndarray:
        """Return the measured displacement [m]."""
        return self.arrays[1]

    @property
    def force(self) -> np.ndarray:
        """Return the measured force [N]."""
        return self.arrays[2]


#: Largest command delay line [steps] (0.5 s at 1024 Hz: far beyond any lab network).
MAX_DELAY_STEPS = 512


class DelayLine:
    """Commands by step, written ``steps`` ticks after their own step (D of the module doc)."""

    def __init__(self, steps: int = 0):
        """Check ``steps`` (parameter ``command_delay_steps``) and start empty."""
        if (isinstance(steps, bool) or not isinstance(steps, (int, float))
                or steps != int(steps) or not 0 <= steps <= MAX_DELAY_STEPS):
            raise ValueError(f'parameter command_delay_steps = {steps!r} must be an integer '
                             f'in [0, {MAX_DELAY_STEPS}] (steps between a command and the tick '
                             'that writes it; 0 = none)')
        self.steps = int(steps)
        self.pending: dict[int, np.ndarray] = {}
        self.first = None

    def receive(self, step: int, command):
        """Keep the command of ``step`` until its tick (step + D)."""
        self.pending[step] = command
        if step == 0:
            self.first = command

    def due(self, tick: int):
        """Return the command to write at ``tick`` (None if not arrived); forget older ones."""
        step = tick - self.steps
        if step < 0:
            return self.first
        command = self.pending.pop(step, None)
        if self.pending and min(self.pending) < step:
            for old in [s for s in self.pending if s < step]:
                del self.pending[old]
        return command


class Bridge:
    """Backend + :class:`~rths_actuator_bridge.safety.SafetySupervisor` + command delay line."""

    def __init__(self):
        """Create an unconfigured bridge."""
        self.backend = None
        self.supervisor = safety.SafetySupervisor()
        self.delay = DelayLine(0)
        self.next_step = 0   # the tick after the last one stepped
        self.last_valid = None   # (displacement, force, channels) of the last valid reading
        self.rig = None          # rths_common.rig.Rig of a multi-actuator rig_file

    @property
    def delay_steps(self) -> int:
        """D: the command of step k is written at tick k + D."""
        return self.delay.steps

    def receive(self, step: int, command):
        """Return a command for ``step`` arrived: it waits in the delay line until tick step + D."""
        self.delay.receive(step, command)

    def due(self, tick: int):
        """Return the command to write at ``tick`` (that of step tick - D), None if missing."""
        return self.delay.due(tick)

    @property
    def state(self) -> int:
        """Safety state number."""
        return self.supervisor.state

    def configure(self, params: dict):
        """Create and configure the backend and the limits from flat parameters."""
        if self.backend is not None:
            self.backend.close()
        params = dict(params)
        self.delay = DelayLine(params.pop('command_delay_steps', 0))
        rig = self.rig = read_rig(params.pop('rig_file', ''))
        sup = self.supervisor
        sup.command_check = sup.measurement_check = None
        if rig is not None:
            params = rig.bridge_params(params)
            if 'n_channels' in backend_class(params).params:
                given = params.get('n_channels')
                if given not in (None, 1, rig.n):      # 1: the one-actuator default
                    raise ValueError(f"parameter 'n_channels' = {given} disagrees with "
                                     f'{rig.where}, which lists {rig.n} actuators; remove '
                                     'n_channels (it follows the rig file) or fix the file')
                params['n_channels'] = rig.n
        self.backend = make_backend(params)
        if rig is not None:
            if self.backend.n_channels != rig.n:
                name = params.get('backend', DEFAULT_BACKEND)
                self.backend.close()
                self.backend = None
                raise ValueError(f'{rig.where} lists {rig.n} actuators but backend {name!r} '
                                 'drives one channel; use backend simulated_rig, or udp '
                                 '(its n_channels follows the file)')
            sup.command_check = rig.check_command
            sup.measurement_check = rig.check_reading
        self.backend.limits.per_channel(self.backend.n_channels)
        sup.configure(self.backend.limits)

    def activate(self, position=0.0):
        """Activate the backend and arm the supervisor at ``position`` [m] (actuator at rest)."""
        if self.backend is None:
            raise RuntimeError('configure the bridge before activating it')
        self.backend.activate()
        self.supervisor.activate(np.full(self.backend.n_channels, position, float))
        self.last_valid = None

    def deactivate(self):
        """Deactivate the backend; the supervisor goes INACTIVE."""
        if self.backend is not None:
            self.backend.deactivate()
        self.supervisor.deactivate()

    def emergency_stop(self, reason: str = '', within_s: float | None = None):
        """Emergency stop: the next steps brake, hold, ramp to the safe position and stop.

        ``within_s``: hold and ramp take about that long (:meth:`SafetySupervisor.emergency_stop`).
        """
        self.supervisor.emergency_stop(reason, within_s)

    def step(self, step: int, command=None, realtime: bool = False) -> StepResult:
        """Run tick ``step``: write ``command`` [m] now (None: none arrived: extrapolate).

        ``realtime``: wait for an external actuator's reading only within the
        tick (the backend's ``reply_wait_s``); lock-step: its own timeout, or one
        sample period while the supervisor holds or ramps without readings.
        """
        sup = self.supervisor
        self.next_step = step + 1
        out, state, fault = sup.filter(step, command)
        backend = self.backend
        if (out is not None and backend is not None and backend.n_channels == 1
                and backend.lifecycle == 'active' and hasattr(backend, 'write_read_one')):
            # one channel, simulated plant: floats through backend and supervisor (same result)
            disp, force, chans = backend.write_read_one(out.item(0))
            sup.check_measurement_one(disp, force, chans.get('rel_disp'))
            if sup.state == safety.STOPPED:
                backend.deactivate()
            if math.isfinite(disp) and math.isfinite(force):
                valid = self.last_valid = (np.array((disp,)), np.array((force,)), chans)
                return StepResult(step, out, valid[0], valid[1], sup.state, sup.fault, chans)
            disp, force, chans = self.last_valid or (out.copy(), np.zeros(1), {})
            return StepResult(step, out, disp, force, sup.state, sup.fault, chans, 1)
        n = backend.n_channels if backend is not None else 1
        if out is None or backend is None or backend.lifecycle != 'active':
            nan = np.full(n, np.nan)
            return StepResult(step, np.zeros(0), nan, nan, sup.state, sup.fault)
        backend.write(out)
        fs = sup.limits.fs_hz
        if realtime:
            wait_s = backend.reply_wait_s(fs)
        else:   # a silent controller must not slow the safe stop
            wait_s = 1.0 / fs if sup.invalid and sup.state != safety.ACTIVE else None
        disp, force = backend.read(None if backend.in_process else wait_s)
        chans = backend.channels()
        if backend.fault:
            sup.trip(backend.fault)
        lost = None if backend.in_process else 'controller stall: no usable reply'
        sup.check_measurement(disp, force, chans.get('rel_disp'),
                              **({'lost': lost} if lost else {}))
        filled = 0
        if np.all(np.isfinite(disp)) and np.all(np.isfinite(force)):
            if self.rig is not None:
                chans = {**chans, **self.interface(disp, force)}
            self.last_valid = (disp, force, chans)
        else:
            filled = 1
            disp, force, chans = self.last_valid or (out.copy(), np.zeros(n), {})
        if sup.state == safety.STOPPED:
            backend.deactivate()
        return StepResult(step, out, disp, force, sup.state, sup.fault, chans, filled)

    def interface(self, displacement, force) -> dict:
        """Return a rig's interface channels of one reading (module doc); {} without a rig."""
        if self.rig is None:
            return {}
        x, theta = self.rig.to_dofs(np.asarray(displacement, float))
        f, m = self.rig.interface_forces(np.asarray(force, float), theta)
        return {'interface_disp': np.array((float(x), float(theta))),
                'interface_force': np.array((float(f), float(m)))}

    def park(self, period_s: float = 0.0, on_step=None) -> list:
        """End the run of an external actuator: ramp to the safe position, then deactivate.

        Only where the actuator moved and outlives the run (not ``backend.in_process``)
        and the supervisor has not stopped it already: it brakes, ramps to
        ``safe_position_m`` within the limits (no fault) and the backend is
        deactivated.  ``period_s`` > 0 paces the steps at that period (realtime;
        lock-step: the controller's replies pace them).  ``on_step(result)`` is
        called after each step, as it happens (the node publishes it).  Returns the steps.
        """
        backend, sup = self.backend, self.supervisor
        if (backend is None or backend.in_process or backend.lifecycle != 'active'
                or sup.last_sent is None):
            return []
        sup.finish()
        lim = sup.limits
        bound = int((lim.hold_time_s + 2 * lim.ramp_time_s + 2.0) * lim.fs_hz)
        results: list = []
        due = time.monotonic()
        while sup.state in (safety.HOLD, safety.RAMP) and len(results) < bound:
            results.append(self.step(self.next_step, None, realtime=period_s > 0))
            if on_step is not None:
                on_step(results[-1])
            if period_s > 0:
                due += period_s
                time.sleep(max(0.0, due - time.monotonic()))
        backend.deactivate()
        return results

    def close(self):
        """Release the backend."""
        if self.backend is not None:
            self.backend.close()

    def cleanup(self):
        """Deactivate and release the backend: unconfigured again (configure() to reuse)."""
        self.deactivate()
        self.close()
        self.backend = None
