"""The interface of a numerical substructure stepped in real time, whatever computes it.

One RTHS loop step k, as the numerical node (or :func:`.reference.coupled_rths`)
drives it::

    u_0 = sub.first_displacement()              # interface displacement of step 0 [m]
    repeat until sub.done():
        u_{k+1} = sub.advance(f_k)              # measured force of step k [N] in

Implementations: :class:`.substructure.NumericalSubstructure` (``backend:
builtin``, the project's own integrators) and
:class:`.opensees_backend.OpenSeesSubstructure` (``backend: opensees``).
``rths_numerical/test/test_backend_contract.py`` runs the same tests on both.
"""

import abc

import numpy as np

#: Values of the ``backend`` parameter of :func:`.substructure.make_substructure`.
BACKENDS = ('builtin', 'opensees')


class SteppedSubstructure(abc.ABC):
    """Interface displacement out, measured force in, one loop step at a time; no ROS.

    Attributes every implementation sets: ``dt`` [s], ``n_steps`` (the run's
    length), ``n_interface`` (interface DOFs, the length of a displacement
    and of a force), ``backend`` (one of :data:`BACKENDS`).
    """

    backend = ''
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
