"""The bridge logic without ROS: a backend guarded by a safety supervisor, one call per step.

The ROS node is a thin shell over :class:`Bridge`: on configure it calls
:meth:`Bridge.configure`, on activate :meth:`Bridge.activate`, per loop step
:meth:`Bridge.step` (with the step's command, or None when none arrived in
time), and on the emergency-stop topic/service :meth:`Bridge.emergency_stop`.
Lifecycle: nothing is written to the backend before configure + activate;
when the supervisor reaches STOPPED the backend is deactivated.
"""

from dataclasses import dataclass, field

import numpy as np

from . import safety
from .backend import make_backend


@dataclass
class StepResult:
    """What one bridge step did (fields map onto Measurement and LoopStatus messages)."""

    step: int
    applied: np.ndarray          # [m] command written (after safety), empty if none
    displacement: np.ndarray     # [m] measured (NaN if lost / nothing written)
    force: np.ndarray            # [N] measured
    state: int                   # safety state (LoopStatus.SAFETY_*)
    fault: str = ''
    channels: dict = field(default_factory=dict)


class Bridge:
    """Backend + :class:`~rths_actuator_bridge.safety.SafetySupervisor`."""

    def __init__(self):
        """Create an unconfigured bridge."""
        self.backend = None
        self.supervisor = safety.SafetySupervisor()

    @property
    def state(self) -> int:
        """Safety state number."""
        return self.supervisor.state

    def configure(self, params: dict):
        """Create and configure the backend and the limits from flat parameters."""
        if self.backend is not None:
            self.backend.close()
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
        """Run loop step ``step`` with ``command`` [m] (None: no command arrived)."""
        sup = self.supervisor
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
