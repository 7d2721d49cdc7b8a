"""The interface of a numerical substructure stepped in real time, whatever computes it.

One RTHS loop step k, as a backend implements it::

    u_0 = sub.first_displacement()              # interface displacement of step 0 [m]
    repeat until sub.done():
        u_{k+1} = sub.advance(f_k)              # measured force of step k [N] in

:class:`NumericalCore` puts a backend behind the loop cores' step contract
(:mod:`rths_common.stepping`): ``core.step(k, f_k)`` with the missing-input
policy (lost forces interpolated); the numerical node and
:mod:`rths_common.replay` step it that way.  Backends:
:class:`.substructure.NumericalSubstructure` (``backend: builtin``, the
project's own integrators) and
:class:`.opensees_backend.OpenSeesSubstructure` (``backend: opensees``).
``rths_numerical/test/test_backend_contract.py`` runs the same tests on both.
"""

import abc

import numpy as np

from rths_common.gaps import FORCE_ORDER
from rths_common.stepping import GapPolicy, StepResult

#: Values of the ``backend`` parameter of :func:`.substructure.make_substructure`.
BACKENDS = ('builtin', 'opensees')


class SteppedSubstructure(abc.ABC):
    """Interface displacement out, measured force in, one loop step at a time; no ROS.

    Attributes every implementation sets: ``dt`` [s], ``n_steps`` (the run's
    length), ``n_interface`` (interface DOFs, the length of a displacement
    and of a force), ``backend`` (one of :data:`BACKENDS`); ``motion``, the
    :class:`.ground_motion.GroundMotion` it runs (None for a prescribed excitation).
    """

    backend = ''
    motion = None
    dt: float
    n_steps: int
    n_interface: int

    @abc.abstractmethod
    def first_displacement(self) -> np.ndarray:
        """Interface displacement command of step 0 [m]."""

    @abc.abstractmethod
    def advance(self, measured_force) -> np.ndarray:
        """Finish step k with its measured force [N]; return the command of step k+1 [m].

        Raises RuntimeError once :meth:`done`.
        """

    @abc.abstractmethod
    def done(self) -> bool:
        """Return True once ``n_steps`` steps are finished."""

    def force_of(self, measured_force) -> np.ndarray:
        """Return ``measured_force`` as ``n_interface`` floats [N] for :meth:`advance`.

        RuntimeError once :meth:`done` (every implementation's first check).
        """
        if self.done():
            raise RuntimeError(f'all {self.n_steps} steps are finished')
        return np.asarray(measured_force, dtype=float).reshape(self.n_interface)

    @abc.abstractmethod
    def history(self) -> dict:
        """Return arrays of the finished steps (SI units).

        At least ``time``, ``interface_disp``, ``output_disp``, ``command`` and
        ``measured_force``.
        """

    @abc.abstractmethod
    def state(self) -> dict:
        """Return the state of the last finished step.

        ``step`` (steps finished), ``time`` [s], ``interface_disp`` [m] and
        ``output_disp`` [m] (NaN before the first step).
        """

    @abc.abstractmethod
    def reset(self) -> None:
        """Return to step 0 at rest with the same model, ground motion and settings."""


class NumericalCore:
    """A :class:`SteppedSubstructure` behind the step contract: measured force k in.

    ``step(k, force)`` finishes step k and returns the interface displacement
    of step k + 1 (none once the run is done).  Missing-input policy: forces
    lost before k are interpolated linearly (:data:`rths_common.gaps.FORCE_ORDER`:
    the force enters the integrator, a low-pass, and carries sensor noise that
    higher orders amplify); a force that is not ``n_interface`` finite values
    is a ValueError naming the step.
    """

    def __init__(self, sub: SteppedSubstructure):
        self.sub = sub
        self.policy = GapPolicy(FORCE_ORDER)

    @property
    def next_step(self) -> int:
        """Return the step whose measured force the core expects next."""
        return self.policy.next_step

    def first_displacement(self) -> np.ndarray:
        """Interface displacement of step 0 [m]."""
        return self.sub.first_displacement()

    def done(self) -> bool:
        """Return True once the run's last step is finished."""
        return self.sub.done()

    def step(self, k: int, force) -> StepResult:
        """Finish step ``k`` with its measured force [N] (filling lost ones before it)."""
        sub = self.sub
        try:
            if len(force) != sub.n_interface:
                self._refuse(k, force)
        except TypeError:   # not a sequence
            self._refuse(k, force)
        x, rows = self.policy.admit(k, force)
        if not np.isfinite(x).all():
            self._refuse(k, force)
        filled = 0
        for row in rows:
            if sub.done():
                break
            sub.advance(row)
            filled += 1
        if sub.done():
            self.policy.passed(k)
            return StepResult(k, (), filled, done=True)
        displacement = sub.advance(x)
        self.policy.passed(k)
        done = sub.done()
        return StepResult(k, () if done else (displacement,), filled, done=done)

    def _refuse(self, k, force):
        values = np.asarray(force, dtype=float).ravel().tolist()
        raise ValueError(f'step {k}: measured force {values} is not '
                         f'{self.sub.n_interface} finite value(s)')

    def reset(self):
        """Back to step 0 (the substructure and the policy)."""
        self.sub.reset()
        self.policy.reset()
