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
"""

import numpy as np

from rths_common import stepping
from rths_common.params import node_schema
from rths_common.registry import Registry

from . import safety
from .backend import Backend
from .simulated import SimulatedBackend
from .udp import UdpBackend

#: Backend name (the ``backend`` parameter) -> class (a :class:`.backend.Backend`, which
#: carries its summary, parameters, ranges and choices).
BACKENDS = Registry('bridge backend', 'backend',
                    {'simulated': SimulatedBackend, 'udp': UdpBackend})
#: The backend of a params file that names none.
DEFAULT_BACKEND = 'simulated'

#: The bridge's own parameters: key -> (default, meaning [unit]).  The backends' are their
#: classes' ``params`` (``simulated.SIM_PARAMS``, ``udp.UDP_PARAMS``), the limits
#: ``safety.SAFETY_PARAMS``.
PARAMS = {
    'backend': (DEFAULT_BACKEND, 'what the bridge drives (rths_actuator_bridge.bridge.BACKENDS)'),
    'command_delay_steps': (0, '[steps] the command of step k is written at tick k + D'),
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
                       choices)


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
                 channels=None):
        super().__init__(step, (applied, displacement, force), 0, state, fault, False, channels)

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
        self.backend = make_backend(params)
        self.supervisor.configure(self.backend.limits)

    def activate(self, position=0.0):
        """Activate the backend and arm the supervisor at ``position`` [m] (actuator at rest)."""
        if self.backend is None:
            raise RuntimeError('configure the bridge before activating it')
        self.backend.activate()
        self.supervisor.activate(np.full(self.backend.n_channels, position, float))

    def deactivate(self):
        """Deactivate the backend; the supervisor goes INACTIVE."""
        if self.backend is not None:
            self.backend.deactivate()
        self.supervisor.deactivate()

    def emergency_stop(self, reason: str = ''):
        """Emergency stop: the next steps brake, hold, ramp to the safe position and stop."""
        self.supervisor.emergency_stop(reason)

    def step(self, step: int, command=None) -> StepResult:
        """Run tick ``step``: write ``command`` [m] now (None: none arrived: extrapolate)."""
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
            return StepResult(step, out, np.array((disp,)), np.array((force,)), sup.state,
                              sup.fault, chans)
        n = self.backend.n_channels if self.backend is not None else 1
        nan = np.full(n, np.nan)
        if out is None or self.backend is None or self.backend.lifecycle != 'active':
            return StepResult(step, np.zeros(0), nan, nan, sup.state, sup.fault)
        self.backend.write(out)
        disp, force = self.backend.read()
        chans = self.backend.channels()
        sup.check_measurement(disp, force, chans.get('rel_disp'))
        if sup.state == safety.STOPPED:
            self.backend.deactivate()
        return StepResult(step, out, disp, force, sup.state, sup.fault, chans)

    def close(self):
        """Release the backend."""
        if self.backend is not None:
            self.backend.close()

    def cleanup(self):
        """Deactivate and release the backend: unconfigured again (configure() to reuse)."""
        self.deactivate()
        self.close()
        self.backend = None
