"""The numerical substructure at a divisor of the loop rate (``rate_divisor``, issue 24).

At 4096 Hz a loop step has 244 us for the three nodes' work.  The structure's
modes are slow against that: its integration does not need every loop step.
With ``rate_divisor: N`` the substructure is integrated at ``fs_hz / N`` and
the loop still runs at ``fs_hz``.  The compensator and the bridge see one
interface displacement per loop step, as before, so no message, topic or bag
changes.  OpenFresco's real-time set-ups do the same with 5x upsampling.

Loop step k, with N loop steps to one numerical step m (k = m N + j, 0 <= j < N)::

    j == 0:  finish numerical step m with the measured force of loop step k,
             x_{m+1} = inner.advance(f_k)     (the integrators used here are explicit)
    output of loop step k + 1 = the parabola through x_{m-1}, x_m, x_{m+1} at s = (j + 1) / N:
             x_m + s (x_{m+1} - x_{m-1}) / 2 + s^2 ((x_{m+1} + x_{m-1}) / 2 - x_m)

* A parabola, not a line: a piecewise-linear target changes its velocity at
  every numerical step, and the specimen's inertia answers that kink with a
  force spike just where the force is sampled.  On the seed's building with the
  valve #4 DTM at 4096 Hz (Kobe x 0.135, 4 s; ``test_multirate.py``), the roof
  displacement differs from the single-rate run by 3.0 % RMS with lines at
  N = 4, by 0.04 % with the parabola.
* The target of loop step (m+1) N is exactly x_{m+1}, and the force measured at
  that loop step finishes numerical step m+1: the force enters the integration
  where the interface is at the numerical step's displacement.  The forces of
  the loop steps in between are recorded (history, bag) but do not enter it.
  Averaging them would delay the force by (N - 1) / 2 loop steps, and a delayed
  restoring force feeds energy into the loop.
* There is no extra delay: x_{m+1} is known at loop step m N, when the first
  interpolated target is due.
* The numerical step's work falls in one loop step of every N. The average
  cost per loop step falls by about (N - 1) / N of the model's step; the cost
  of that one loop step does not.
* The ground motion is prepared at the loop rate as before, then the
  substructure takes every N-th sample.  So its time grid is a subset of the
  loop's, and the history's ground acceleration is the loop-rate record.

:func:`.substructure.make_substructure` builds it from the parameter
``rate_divisor`` (1, the default, gives the plain substructure).  Its history is
at the loop rate: the commands and forces of every loop step, the response
interpolated linearly between the numerical steps.  Measured cost
and J-values at 4096 Hz: docs/performance.md.
"""

import numpy as np

from .stepping import SteppedSubstructure

#: Attributes of the inner substructure that describe the model, not its rate: shared.
MODEL_ATTRIBUTES = ('model', 'iface', 'force_scale', 'frame', 'specimen_mass', 'integrator')


class MultiRateSubstructure(SteppedSubstructure):
    """A substructure integrated every ``divisor`` loop steps, interpolated in between (module doc).

    ``inner`` is the substructure at the lower rate (``dt * divisor``, every
    ``divisor``-th sample of the record); ``ground_accel`` and ``ground_disp``
    are the loop-rate record it was taken from [m/s^2, m]; ``motion`` its
    :class:`.ground_motion.GroundMotion` at the loop rate.
    """

    def __init__(self, inner: SteppedSubstructure, divisor: int, ground_accel, ground_disp,
                 motion=None):
        divisor = int(divisor)
        if divisor < 2:
            raise ValueError(f'rate_divisor = {divisor}: a multi-rate substructure needs 2 or '
                             'more (1 is the plain substructure)')
        self.inner = inner
        self.divisor = divisor
        self.backend = inner.backend
        self.motion = motion
        self.ag = np.asarray(ground_accel, dtype=float)
        self.ug = np.asarray(ground_disp, dtype=float)
        self.n_steps = int(self.ag.size)
        expected = -(-self.n_steps // divisor)
        if inner.n_steps != expected:
            raise ValueError(f'the inner substructure has {inner.n_steps} steps; every '
                             f'{divisor}-th of {self.n_steps} loop steps is {expected}')
        self.dt = inner.dt / divisor
        self.n_interface = inner.n_interface
        # the model's description, as the run summary, the review and the bag read it
        for name in MODEL_ATTRIBUTES:
            if hasattr(inner, name):
                setattr(self, name, getattr(inner, name))
        self.reset()

    def reset(self):
        """Return to loop step 0 at rest (the inner substructure too)."""
        self.inner.reset()
        self._k = 0
        self._xp = self._x0 = self._x1 = self.inner.first_displacement()
        self._cmd = np.zeros((self.n_steps, self.n_interface))
        self._force = np.zeros((self.n_steps, self.n_interface))
        self._cmd[0] = self._x0

    def first_displacement(self) -> np.ndarray:
        """Interface displacement command of loop step 0 [m]."""
        return self._cmd[0].copy()

    def advance(self, measured_force) -> np.ndarray:
        """Finish loop step k with its measured force [N]; return the command of step k+1 [m]."""
        f = self.force_of(measured_force)
        k = self._k
        j = k % self.divisor
        if j == 0:
            self._xp, self._x0 = self._x0, self._x1
            self._x1 = self.inner.advance(f)
            # the parabola through x_{m-1}, x_m, x_{m+1}: x_m + s b + s^2 c, s in (0, 1]
            self._b = 0.5 * (self._x1 - self._xp)
            self._c = 0.5 * (self._x1 + self._xp) - self._x0
        self._force[k] = f
        self._k = k + 1
        if j + 1 == self.divisor:
            cmd = self._x1.copy()
        else:
            s = (j + 1) / self.divisor
            cmd = self._x0 + s * self._b + (s * s) * self._c
        if k + 1 < self.n_steps:
            self._cmd[k + 1] = cmd
        return cmd

    def done(self) -> bool:
        """Return True once ``n_steps`` loop steps are finished."""
        return self._k >= self.n_steps

    def _at_loop_rate(self, values, k: int) -> np.ndarray:
        """Interpolate the inner steps' ``values`` (rows) linearly to loop steps 0..k-1.

        After the inner's last finished step the value is held.
        """
        values = np.asarray(values, dtype=float)
        at = np.arange(k) / self.divisor
        where = np.arange(len(values))
        if values.ndim == 1:
            return np.interp(at, where, values)
        return np.column_stack([np.interp(at, where, col) for col in values.T]).reshape(
            k, *values.shape[1:])

    def history(self) -> dict:
        """Arrays of the finished loop steps (SI units), the inner's interpolated to the loop rate.

        ``command`` and ``measured_force`` are those of each loop step;
        ``ground_accel`` and ``ground_disp`` the loop-rate record; the response
        (``displacements``, ``output_disp``, ``output_accel_abs``, ``interface_disp``)
        is the inner's, interpolated linearly (held after the last finished
        numerical step).
        """
        k = self._k
        inner = self.inner.history()
        out = {'time': np.arange(k) * self.dt, 'ground_accel': self.ag[:k].copy(),
               'ground_disp': self.ug[:k].copy(), 'command': self._cmd[:k].copy(),
               'measured_force': self._force[:k].copy()}
        if k == 0:
            return {**{key: value[:0] for key, value in inner.items()}, **out}
        for key, value in inner.items():
            if key not in out:
                out[key] = self._at_loop_rate(value, k)
        return out

    def state(self) -> dict:
        """Loop step count, time [s], interface and output displacement [m] of the last step."""
        k = self._k
        if k == 0:
            return {'step': 0, 'time': float('nan'),
                    'interface_disp': np.full(self.n_interface, np.nan),
                    'output_disp': float('nan')}
        h = self.history()
        return {'step': k, 'time': (k - 1) * self.dt,
                'interface_disp': np.asarray(h['interface_disp'][-1], dtype=float).copy(),
                'output_disp': float(h['output_disp'][-1])}
