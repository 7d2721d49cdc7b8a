"""The step contract of the three loop cores, their missing-input policy and the loop drivers.

No ROS here.  Every loop core (the numerical substructure, the compensator,
the actuator bridge) is stepped the same way::

    result = core.step(k, u)    # u: the input of step k; core.next_step: the step it expects

and returns a :class:`StepResult`: the arrays of its output message, how many
missing inputs its policy filled, the safety state and fault text, and
whether the core is done.  ``k`` may be beyond ``core.next_step`` (inputs
were lost on the way): the core fills the steps in between by its
missing-input policy (:class:`GapPolicy` for the numerical and compensator
cores; the bridge's input is None for a missing command, which its safety
supervisor extrapolates).  A ``k`` below ``next_step`` is a stale input, a
ValueError: the driver drops stale inputs before they reach a core.

Two ways to hand ``k`` to a core, one per timing mode (``mode`` parameter):

* :class:`Driver`: the arrival of input k steps the core; in lock-step only
  the step the core expects is taken (any other is rejected), in realtime
  (``lockstep=False``) every input newer than the last one (a gap is filled);
* :class:`TickClock`: the actuator bridge's realtime clock; tick k is due at
  ``t0 + k / fs`` whatever has arrived.  The bridge node (and, composed, the
  container's spin loop, ``node_support.spin_clocked``) asks it when the next
  tick is due and takes the tick from it.

The node around a core converts the message into ``(k, u)``
(:mod:`rths_common.transport`), feeds the driver and converts the result
back; :mod:`rths_common.replay` drives the three cores the same way without ROS.
"""

from types import MappingProxyType

import numpy as np

from rths_common.gaps import GapFiller

_NO_CHANNELS: MappingProxyType = MappingProxyType({})


class StepResult:
    """What one core step produced (the arrays map onto the core's output message).

    ``step``: the input step k the call finished; ``arrays``: the output
    message's arrays (numerical: the interface displacement of step k + 1,
    none once done; compensator: the command of step k; bridge: applied,
    displacement, force of step k) [SI]; ``filled``: inputs lost before k that
    the missing-input policy filled; ``state``/``fault``: safety state
    (``LoopStatus.SAFETY_*``) and fault text; ``done``: the core has finished
    its run; ``channels``: extra named sensor channels (bridge).
    """

    __slots__ = ('step', 'arrays', 'filled', 'state', 'fault', 'done', 'channels')

    def __init__(self, step: int, arrays: tuple = (), filled: int = 0, state: int = 0,
                 fault: str = '', done: bool = False, channels=None):
        self.step = step
        self.arrays = arrays
        self.filled = filled
        self.state = state
        self.fault = fault
        self.done = done
        self.channels = _NO_CHANNELS if channels is None else channels

    @property
    def output(self):
        """Return the first output array (None if the step produced none)."""
        return self.arrays[0] if self.arrays else None

    def __repr__(self) -> str:
        """Show the fields."""
        return (f'StepResult(step={self.step}, arrays={self.arrays!r}, filled={self.filled}, '
                f'state={self.state}, fault={self.fault!r}, done={self.done})')


class StaleStep(ValueError):
    """Input of a step the core has already passed."""


class GapPolicy:
    """Missing-input policy of a core fed by messages: interpolate over lost steps.

    ``order`` is the interpolation order of :class:`rths_common.gaps.GapFiller`
    (:data:`~rths_common.gaps.FORCE_ORDER` for the numerical core,
    :data:`~rths_common.gaps.DISPLACEMENT_ORDER` for the compensator).  Inputs
    lost before the first one received cannot be interpolated: they take the
    first received value.
    """

    def __init__(self, order: int):
        self.order = int(order)
        self.reset()

    def reset(self):
        """Forget every input: the next one is step 0."""
        self.next_step = 0
        self.gaps = GapFiller(self.order)

    def admit(self, k: int, u) -> tuple:
        """Return ``(x, rows)``: input k as an array and one row per lost step next_step..k-1.

        Raises :class:`StaleStep` for ``k < next_step``.  Does not move
        ``next_step``: the core does once it has stepped (:meth:`passed`).
        """
        if k < self.next_step:
            raise StaleStep(f'input of step {k} is stale: the core expects step '
                            f'{self.next_step}')
        x = np.array(u, dtype=float)
        lost = k - self.next_step
        rows = self.gaps.fill(k, x)
        if lost and len(rows) != lost:   # nothing received before: the new value
            return x, [x] * lost
        return x, rows

    def passed(self, k: int):
        """Step ``k`` is done: the next input expected is k + 1."""
        self.next_step = k + 1


class Driver:
    """Steps a core on each arriving input ``(k, u)``: lock-step, or newest-first (realtime).

    ``lockstep`` True: only ``k == core.next_step`` is stepped; False: any
    ``k >= core.next_step`` (the core fills a gap).  Other inputs are
    rejected, counted in ``rejected`` and passed to ``on_reject(k, expected)``.
    ``step`` replaces ``core.step`` (the bridge's lock-step tick).
    """

    def __init__(self, core, lockstep: bool = True, on_reject=None, step=None):
        self.core = core
        self.lockstep = bool(lockstep)
        self.on_reject = on_reject
        self.rejected = 0
        self._step = step or core.step

    def feed(self, k: int, u):
        """Step the core with input ``k``; return its StepResult (None: rejected or waiting)."""
        expected = self.core.next_step
        if k != expected and (self.lockstep or k < expected):
            self.rejected += 1
            if self.on_reject is not None:
                self.on_reject(k, expected)
            return None
        return self._step(k, u)


class TickClock:
    """The realtime clock that hands ``k`` to the bridge: tick k is due at ``t0 + k * period``.

    A tick taken more than a period late is a stall: the clock re-anchors
    (``t0`` moves so the next tick is a period after this one, instead of
    bursting to catch up), counts an overrun and reports the skipped ticks,
    which the bridge's safety policy counts as missing commands.
    """

    def __init__(self, fs_hz: float):
        self.period_ns = int(round(1e9 / fs_hz))
        self.t0_ns: int | None = None   # monotonic time of tick 0 (None: not started)
        self.k = 0          # the next tick's step
        self.overruns = 0

    @property
    def running(self) -> bool:
        """Return True once tick 0 is set."""
        return self.t0_ns is not None

    def start(self, now_ns: int):
        """Tick 0 is ``now_ns`` (monotonic)."""
        self.t0_ns = now_ns

    def due_ns(self) -> int:
        """Monotonic time of the next tick (the clock must be running)."""
        assert self.t0_ns is not None, 'TickClock.start() first'
        return self.t0_ns + self.k * self.period_ns

    def take(self, now_ns: int) -> tuple:
        """Take the next tick at ``now_ns``; return ``(k, late_ns, skipped_ticks)``."""
        k = self.k
        late_ns = now_ns - self.due_ns()
        skipped = 0
        if late_ns > self.period_ns:
            self.overruns += 1
            self.t0_ns = now_ns - k * self.period_ns
            skipped = late_ns // self.period_ns
        self.k = k + 1
        return k, late_ns, skipped
