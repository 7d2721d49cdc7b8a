"""One backend interface for the simulated plant and the real servo controller.

In the spirit of ros2_control's hardware interface: a backend is created
UNCONFIGURED, :meth:`Backend.configure` (params) makes it INACTIVE,
:meth:`Backend.activate` makes it ACTIVE, and only then may
:meth:`Backend.write` / :meth:`Backend.read` be called; :meth:`Backend.deactivate`
returns it to INACTIVE.  :attr:`Backend.limits` declares the
:class:`~rths_actuator_bridge.safety.SafetyLimits` the bridge enforces.

Timing convention (shared with rths_compensator): at step k the bridge writes
command ``u_k`` [m]; it is held (ZOH) for one sample period and ``read()``
returns the measurement at the END of that period, labelled step k.  The
simulated backend advances its plant by exactly one sample per ``write()``
(deterministic lock-step); with the UDP backend the controller does it.

The backends (:class:`rths_actuator_bridge.simulated.SimulatedBackend`,
:class:`rths_actuator_bridge.udp.UdpBackend`) import this module only; the
table of backend names is :data:`rths_actuator_bridge.bridge.BACKENDS`, where
a backend is chosen.  Their parameters (flat, as ROS parameters):

Simulated backend
    see :data:`rths_actuator_bridge.simulated.SIM_PARAMS` (``fs_hz``,
    ``actuator_model``, ``dtm``, ``frame_mass_kg``, noise, ADC, ``seed``, friction).
UDP backend
    see :data:`rths_actuator_bridge.udp.UDP_PARAMS` (``host``, ``port``,
    ``timeout_s``, ``reply_budget``, ``n_channels``, ``protocol_version``, ...).
Safety limits (both)
    see :data:`rths_actuator_bridge.safety.SAFETY_PARAMS`.
"""

from abc import ABC, abstractmethod
import inspect

import numpy as np

from .safety import SafetyLimits

UNCONFIGURED = 'unconfigured'
INACTIVE = 'inactive'
ACTIVE = 'active'


class Backend(ABC):
    """Abstract actuator backend: configure, activate, write, read, deactivate, limits.

    A backend class also says what it is and which parameters it takes, for the
    registry :data:`rths_actuator_bridge.bridge.BACKENDS` and the bridge's schema:
    ``summary`` (one line), ``params`` (key -> (type, default, meaning [unit])),
    ``ranges`` (key -> inclusive (low, high)) and ``choices`` (key -> allowed values);
    ``in_process``: the plant lives in the bridge's process (it stops with it, and the
    pre-flight check may build it); otherwise the actuator is external (a servo
    controller): it outlives the run, so the bridge ends every run by ramping it to
    the safe position before deactivating it.  ``fault`` is a fault the backend itself
    reports (e.g. the controller restarted), '' if none.
    """

    summary = ''
    params: dict = {}
    ranges: dict = {}
    choices: dict = {}
    in_process = False
    fault = ''

    @classmethod
    def make_safe(cls, params: dict) -> str:
        """After the bridge process died: bring the actuator to rest from outside; say how.

        An in-process plant stopped with the bridge; a backend driving hardware
        overrides this (OSError when it cannot reach the controller).
        """
        if cls.in_process:
            return (f'the {cls.summary.split(":")[0]} ran inside the bridge process and stopped '
                    'with it: safe state (nothing moves)')
        raise OSError('this backend cannot stop the actuator from outside the bridge')

    def __init__(self):
        """Create an unconfigured backend."""
        # a backend whose _read takes wait_s waits for an external reading at most that long
        self._timed_reads = 'wait_s' in inspect.signature(self._read).parameters
        self.lifecycle = UNCONFIGURED
        self._limits = SafetyLimits()
        self.n_channels = 1
        self.step = -1

    @property
    def limits(self) -> SafetyLimits:
        """Return the declared safety limits, from the configure parameters."""
        return self._limits

    def configure(self, params: dict):
        """Validate ``params``, prepare the hardware/plant; UNCONFIGURED/INACTIVE -> INACTIVE."""
        if self.lifecycle == ACTIVE:
            raise RuntimeError('deactivate the backend before configuring it again')
        self._limits = SafetyLimits.from_params(params)
        self._configure(dict(params))
        self.lifecycle = INACTIVE

    def activate(self):
        """Start: INACTIVE -> ACTIVE.  Returns nothing; the actuator is at rest."""
        if self.lifecycle != INACTIVE:
            raise RuntimeError(f'activate() needs a configured, inactive backend '
                               f'(state: {self.lifecycle})')
        self._activate()
        self.step = -1
        self.lifecycle = ACTIVE

    def deactivate(self):
        """Stop: ACTIVE -> INACTIVE (no-op otherwise)."""
        if self.lifecycle == ACTIVE:
            self._deactivate()
            self.lifecycle = INACTIVE

    def write(self, command) -> None:
        """Send the command [m] (one value per channel) of the next step."""
        if self.lifecycle != ACTIVE:
            raise RuntimeError(f'write() on a backend that is not active '
                               f'(state: {self.lifecycle})')
        u = np.atleast_1d(np.asarray(command, float))
        if u.shape != (self.n_channels,):
            raise ValueError(f'command has {u.size} values; this backend has {self.n_channels} '
                             'channel(s)')
        if not np.all(np.isfinite(u)):
            raise ValueError(f'refusing non-finite command {u}')
        self.step += 1
        self._write(u)

    def read(self, wait_s=None):
        """Return ``(displacement [m], force [N])`` arrays measured at the end of this step.

        ``wait_s``: the longest wait for an external actuator's reading [s] (None:
        the backend's own timeout); a reading that is not there in time is NaN.
        """
        if self.lifecycle != ACTIVE:
            raise RuntimeError(f'read() on a backend that is not active (state: {self.lifecycle})')
        if wait_s is None or not self._timed_reads:
            return self._read()
        return self._read(wait_s)

    def reply_wait_s(self, fs_hz: float) -> float:
        """Realtime: the longest wait for a reading after a write [s] (0: it is immediate)."""
        return 0.0

    def counts(self) -> dict:
        """Return the counts of an external actuator's replies for the reports ({} if none)."""
        return {}

    def channels(self) -> dict:
        """Extra channels of the latest reading (e.g. 'rel_disp', 'table_accel'); may be empty."""
        return {}

    def close(self):
        """Release resources (sockets); deactivates first."""
        self.deactivate()

    @abstractmethod
    def _configure(self, params: dict):
        """Backend-specific configuration."""

    @abstractmethod
    def _activate(self):
        """Backend-specific activation."""

    @abstractmethod
    def _deactivate(self):
        """Backend-specific deactivation."""

    @abstractmethod
    def _write(self, command: np.ndarray):
        """Backend-specific write of a validated command."""

    @abstractmethod
    def _read(self, wait_s=None):
        """Backend-specific read (``wait_s`` as in :meth:`read`; only given when not None)."""
