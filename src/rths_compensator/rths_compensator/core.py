"""The compensator core behind the loop cores' step contract (no ROS).

``CompensatorCore(params).step(k, x)``: the interface displacement of step k
in, the command of step k out (a :class:`rths_common.stepping.StepResult`),
through the designed filter ``G = taps / denominator`` per interface DOF
(:class:`~rths_compensator.filters.MultiChannelFilter`), a coupled N x N FIR
(``coupled_taps``, :class:`~rths_compensator.filters.CoupledFir`) or an adaptive
method started from it (:mod:`rths_compensator.adaptive`) or the reference
feedback controller (:mod:`rths_compensator.feedback`), parameter ``method``.
The compensator node and :mod:`rths_common.replay` step it.

Missing-input policy: displacements lost before k are interpolated
(:data:`rths_common.gaps.DISPLACEMENT_ORDER`, cubic: the designed taps turn a
held displacement into a command spike) and filtered, so the filter's delay
line sees one value per step.  A method on the measurement (adaptive or
feedback) needs measurement k - 1 for command k.  Lock-step: until
:meth:`CompensatorCore.measure` brings it, ``step`` returns None and keeps the
displacement.  Realtime (``realtime=True``): ``step`` never waits; it uses
measurement k - 1 if it has arrived, else none (the method holds its last
measurement and does not adapt on this step), and lost displacements are
interpolated as for the designed filter.

Load feed-forward (:mod:`.feedforward`, the ``feedforward_*`` parameters that
``rths design`` writes from an updated actuator model's non-linear loads): the load
evaluated on the interface displacements is added to every method's command; a lost
displacement steps it like the filter.
"""

from typing import Any

import numpy as np

from rths_common.gaps import DISPLACEMENT_ORDER
from rths_common.stepping import GapPolicy, StaleStep, StepResult
from rths_compensator.filters import CoupledFir, MultiChannelFilter

from .feedforward import from_params as feedforward_from
from .methods import method_of, uses_measurement
from .params import coupled_taps_of


class CompensatorCore:
    """The designed (or adaptive) compensator, one step per interface displacement.

    ``params``: the validated compensator parameters (``taps``, ``denominator``,
    ``fs_hz``, ``scheme``, ``method``, ``provenance``...).  The filter is built
    on the first step, when the number of interface DOFs is known.
    """

    def __init__(self, params: dict, realtime: bool = False):
        self.params = params
        self.adaptive = uses_measurement(method_of(params))   # steps on the measurement
        self.realtime = bool(realtime)
        self.filter: Any = None   # MultiChannelFilter or adaptive.ChannelMethods
        self.policy = GapPolicy(DISPLACEMENT_ORDER)
        self.measured: dict = {}   # adaptive: step -> (measured displacement, applied)
        self.pending: tuple | None = None   # adaptive: (k, x) waiting for measurement k - 1
        self.last_target: np.ndarray | None = None   # the last step's interface displacement
        self.feedforward = feedforward_from(params)   # None: no load feed-forward
        self._ff_last = None   # the feed-forward of the last step

    @property
    def next_step(self) -> int:
        """Return the step whose interface displacement the core expects next."""
        return self.policy.next_step

    def _build(self, n_channels: int):
        if self.adaptive:
            # lazy: start-up cost: SciPy (~1 s), which this module needs only here
            from rths_compensator.adaptive import methods_from_params
            return methods_from_params(self.params, n_channels)
        coupled = coupled_taps_of(self.params)
        if coupled is not None:
            return CoupledFir.from_flat(coupled, n_channels)
        return MultiChannelFilter(self.params['taps'], self.params['denominator'],
                                  n_channels=n_channels)

    def warm_up(self, n_channels: int = 1):
        """Build the filter for ``n_channels`` and run its code paths (realtime start-up).

        A method on the measurement is built here (imports, the plant) and stepped on
        throwaway copies; the run's own one starts fresh.
        """
        MultiChannelFilter(self.params['taps'], self.params['denominator'],
                           n_channels=1).step(np.zeros(1))
        if self.adaptive:
            spare = self._build(n_channels)
            zero = np.zeros(n_channels)
            for _ in range(8):
                spare.step(zero, zero, None)
            self.filter = self._build(n_channels)

    def step(self, k: int, x) -> StepResult | None:
        """Return the command of step ``k`` for its interface displacement ``x`` [m].

        None: an adaptive method waits for measurement k - 1 (x is kept).
        """
        if self.adaptive:
            return self._adaptive_step(k, x)
        x, rows = self.policy.admit(k, x)
        self.last_target = x
        filt = self.filter
        if filt is None:
            filt = self.filter = self._build(max(x.size, 1))
        for row in rows:   # lost displacements: interpolated (or x, if nothing came before)
            filt.step(row)
            self._load(row)
        command = filt.step(x) + self._load(x)
        self.policy.passed(k)
        return StepResult(k, (command,), len(rows))

    def _load(self, x):
        """Return the load feed-forward of the displacement ``x`` (0.0 when it is off)."""
        if self.feedforward is None:
            return 0.0
        self._ff_last = self.feedforward.step(x)
        return self._ff_last

    def _method_applied(self, applied):
        """Return the previous step's applied commands without their feed-forward.

        That is what the adaptive method commanded: it compares them with its own
        commands to see a bridge's hold, ramp or limit.
        """
        if applied is None or self.feedforward is None or self._ff_last is None:
            return applied
        return np.asarray(applied, dtype=float) - self._ff_last

    def _adaptive_step(self, k, x):
        if self.realtime:
            return self._adaptive_realtime(k, x)
        if k != self.next_step:
            raise StaleStep(f'adaptive compensator: step {k} is not the expected step '
                            f'{self.next_step} (adaptive methods run in lock-step)')
        x = self.last_target = np.asarray(x, dtype=float)
        if k > 0 and (k - 1) not in self.measured:
            self.pending = (k, x)
            return None
        self.pending = None
        if self.filter is None:
            self.filter = self._build(max(x.size, 1))
        prev, applied = self.measured.pop(k - 1, (None, None))
        command = self.filter.step(x, prev, self._method_applied(applied)) + self._load(x)
        self.policy.passed(k)
        return StepResult(k, (command,), 0, fault=self.filter.fallback)

    def _adaptive_realtime(self, k, x):
        x, rows = self.policy.admit(k, x)
        self.last_target = x
        filt = self.filter
        if filt is None or len(filt.methods) != max(x.size, 1):
            filt = self.filter = self._build(max(x.size, 1))
        measured = self.measured
        first = self.next_step
        for i, row in enumerate(rows):   # lost displacements: interpolated
            prev, applied = measured.pop(first + i - 1, (None, None))
            filt.step(row, prev, self._method_applied(applied))
            self._load(row)
        prev, applied = measured.pop(k - 1, (None, None))
        command = filt.step(x, prev, self._method_applied(applied))
        if self.feedforward is not None:
            command = command + self._load(x)
        if measured:
            for old in [j for j in measured if j < k]:   # late ones: never used
                del measured[old]
        self.policy.passed(k)
        return StepResult(k, (command,), len(rows), fault=filt.fallback)

    def measure(self, k: int, displacement, applied) -> StepResult | None:
        """Keep measurement k; lock-step: return the result of step k + 1 if it was waiting."""
        if self.realtime:
            if k >= self.next_step - 1:
                self.measured[k] = (displacement, applied)
            return None
        self.measured[k] = (displacement, applied)
        if self.pending is not None and self.pending[0] == k + 1:
            return self._adaptive_step(*self.pending)
        return None

    def coefficients(self) -> np.ndarray:
        """Adaptive: the current coefficients of every channel."""
        return self.filter.coefficients()
