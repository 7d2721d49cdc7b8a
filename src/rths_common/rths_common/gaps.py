"""Filling lost steps of a sampled vector signal by interpolation (realtime loop; no ROS here).

In realtime mode the loop topics are best-effort: a node can receive step a,
lose steps a+1 .. b-1 and receive step b.  The receiving node must still feed
its core one value per step (the compensator's filter delay line, the
numerical model's integrator).  When step b arrives both ends of the gap are
known, so the lost values are *interpolated*, not held.

Why not hold.  Holding x_a over the gap is an input error that grows like the
signal's slope (``dt`` = sample period, step a+m of a gap a..b)::

    hold:    |x_{a+m} - x_a|  <=  max|x'| * m * dt

A designed compensator has a large high-frequency gain (the WLS taps of
``config/compensator.yaml`` start 647, -1791, 1806: high-pass in the
stopband, seed section 4.3), so that single-step error, about 1e-4 m at
0.1 m/s and 1024 Hz, becomes a command spike of up to 0.18 m that trips the
actuator bridge's velocity limit (``src/rths_compensator/test/test_lost_displacement.py``).

Interpolation error.  A polynomial of order p through the nodes t_0..t_p
(steps with known values) has the Lagrange remainder::

    |x(t) - P(t)|  <=  max|x^(p+1)| / (p+1)! * prod_i |t - t_i| * dt^(p+1)

(:func:`error_bound`).  For the linear case (p = 1, nodes a and b = a + n)
that is ``max|x''| * m (n - m) / 2 * dt^2 <= max|x''| * n^2 * dt^2 / 8``;
one lost step (n = 2) gives ``max|x''| * dt^2 / 2``: per lost step a factor
of about ``|x'| / (|x''| dt / 2)`` (hundreds at 1-3 Hz and 1024 Hz) below hold.
That is still not enough behind the designed 400-tap compensator: the
remaining error (bound 6e-7 m at 1.2 m/s^2), amplified by the tap
differences (up to 3597 at 1024 Hz), exceeds the bridge's acceleration limit
(400 m/s^2) at 11 of 12 lost-step positions of the 1-3 Hz, 10 mm test signal
(same test).  A cubic through the last three consecutively received steps
and the new one (nodes a-2, a-1, a, b) leaves ``max|x''''| * dt^4 / 4`` for
one lost step, about 6e-11 m there: a command error below 1.1e-7 m.

Policy of :class:`GapFiller` (one per signal):

* nodes: the new step b and up to ``order`` last *received* steps (never
  interpolated values; they may straddle an earlier gap: back-to-back losses
  such as 199, 201, 203 keep a cubic through 198, 199, 201 and 203);
* the order is the highest (at most ``order``) whose Lebesgue constant over
  the gap, ``max_t sum_i |l_i(t)|``, is at most :data:`MAX_LEBESGUE` (8): it
  bounds how much an error in the nodes (round-off, sensor noise) can grow in
  the filled values.  A cubic through contiguous nodes has 3.0 / 5.0 / 7.4
  for 1 / 2 / 3 lost steps and 11.0 for 4, where a quadratic (3.0) takes
  over; linear (1.0) is the last resort, from about 15 lost steps on;
* nothing received yet: nothing to interpolate from; :meth:`GapFiller.fill`
  returns no rows and the caller keeps its own start-up rule.

The compensator node fills lost interface displacements with
:data:`DISPLACEMENT_ORDER` (cubic); the numerical node fills lost measured
forces with :data:`FORCE_ORDER` (linear: the force enters the integrator, a
low-pass, and carries sensor noise that higher orders amplify).
"""

from collections import deque
import functools
import math

import numpy as np

#: Interpolation order for lost interface displacements (compensator node): cubic.
DISPLACEMENT_ORDER = 3
#: Interpolation order for lost measured forces (numerical node): linear.
FORCE_ORDER = 1
#: Largest Lebesgue constant over a gap (the policy lowers the order until it holds).
MAX_LEBESGUE = 8.0


def lagrange_weights(nodes, targets) -> np.ndarray:
    """Weights ``W`` (len(targets) x len(nodes)): ``P(targets) = W @ values(nodes)``.

    ``nodes`` are distinct step indices (any spacing), ``targets`` the steps to
    evaluate the interpolating polynomial of order ``len(nodes) - 1`` at.
    """
    t = np.asarray(nodes, dtype=float).ravel()
    s = np.asarray(targets, dtype=float).ravel()
    if t.size == 0:
        raise ValueError('interpolation needs at least one node')
    if np.unique(t).size != t.size:
        raise ValueError(f'interpolation nodes must be distinct steps, got {t.tolist()}')
    w = np.ones((s.size, t.size))
    for i in range(t.size):
        for j in range(t.size):
            if j != i:
                w[:, i] *= (s - t[j]) / (t[i] - t[j])
    return w


@functools.lru_cache(maxsize=256)
def _gap_weights(known: tuple, n_missing: int):
    """Weights and Lebesgue constant for nodes ``known + (0,)`` over steps -n_missing..-1.

    Steps are relative to the new one; gap patterns repeat, so they are cached
    (a miss costs a dict lookup instead of ~70 us of small-array arithmetic).
    """
    weights = lagrange_weights(known + (0,), np.arange(-n_missing, 0))
    weights.setflags(write=False)
    return weights, float(np.max(np.abs(weights).sum(axis=1)))


def interpolate(steps, values, missing) -> np.ndarray:
    """Values at the steps ``missing`` of the polynomial through ``(steps, values)``.

    ``values`` has one row per step (a vector per step: one column per DOF);
    the result has one row per missing step.  Exact for polynomials of order
    ``len(steps) - 1``; error bound: :func:`error_bound`.
    """
    v = np.asarray(values, dtype=float)
    v = v.reshape(len(v), -1)
    if v.shape[0] != len(steps):
        raise ValueError(f'{len(steps)} steps but {v.shape[0]} value rows')
    origin = steps[-1]  # relative steps keep the products small
    return lagrange_weights(np.asarray(steps) - origin, np.asarray(missing) - origin) @ v


def error_bound(steps, missing, derivative_max: float, dt: float) -> np.ndarray:
    """Lagrange remainder bound on ``|x - P|`` at each missing step [units of x].

    ``derivative_max`` is ``max|x^(p+1)|`` over the gap (p = ``len(steps) - 1``,
    e.g. ``max|x''|`` [m/s^2] for linear interpolation of a displacement), ``dt``
    the sample period [s]::

        max|x^(p+1)| / (p+1)! * prod_i |t - t_i| * dt^(p+1)
    """
    p = len(steps) - 1
    s = np.asarray(missing, dtype=float).reshape(-1, 1)
    prod = np.prod(np.abs(s - np.asarray(steps, dtype=float).reshape(1, -1)), axis=1)
    return derivative_max / math.factorial(p + 1) * prod * dt ** (p + 1)


def hold_error_bound(last_step: int, missing, velocity_max: float, dt: float) -> np.ndarray:
    """Bound on the error of holding the value of ``last_step``: ``max|x'| * m * dt``."""
    return velocity_max * (np.asarray(missing, dtype=float) - last_step) * dt


class GapFiller:
    """Remembers the last received steps of one signal; interpolates over the steps lost since.

    Call :meth:`fill` with every received step, in increasing step order.  The
    policy (nodes, order) is in the module docstring.
    """

    def __init__(self, order: int = 1):
        order = int(order)
        if order < 1:
            raise ValueError(f'interpolation order must be >= 1, got {order}')
        self.order = order
        self._steps: deque[int] = deque(maxlen=order)   # the last received steps, oldest first
        self._values: deque[np.ndarray] = deque(maxlen=order)
        self.last_nodes: list[int] = []     # steps the last gap was interpolated through

    @property
    def last_step(self):
        """Return the last step received, or None."""
        return self._steps[-1] if self._steps else None

    def fill(self, step: int, value) -> np.ndarray:
        """Record ``value`` of ``step``; return interpolated values of the steps lost before it.

        The result has one row per lost step ``last_step + 1 .. step - 1`` (no
        rows if none was lost, or if nothing was received before: there is no
        left end to interpolate from).  ``step`` must be above the last one
        (ValueError): stale and repeated steps are the caller's to drop.
        """
        x = np.array(value, dtype=float).ravel()
        last = self.last_step
        filled = np.empty((0, x.size))
        if last is not None:
            if step <= last:
                raise ValueError(f'step {step} is not after the last received step {last}')
            if step - last > 1:
                known = tuple(int(k) - int(step) for k in self._steps)  # relative to step
                for n in range(len(known), 0, -1):   # highest order first
                    weights, lebesgue = _gap_weights(known[-n:], int(step - last - 1))
                    if n == 1 or lebesgue <= MAX_LEBESGUE:
                        break
                self.last_nodes = [k + int(step) for k in known[-n:]] + [int(step)]
                filled = weights @ np.vstack(list(self._values)[-n:] + [x])
        self._steps.append(int(step))
        self._values.append(x)
        return filled


def warm_up(order: int, max_lost: int = 3, n_channels: int = 1) -> None:
    """Run :meth:`GapFiller.fill` over gaps of 1..``max_lost`` steps once (realtime start-up).

    The first call of a code path is slow (numpy dispatch, the weights cache);
    a node calls this before its loop so a miss costs ~10 us, not ~1 ms.
    """
    filler = GapFiller(order)
    step = 0
    for lost in range(1, int(max_lost) + 1):
        for _ in range(order):   # the history, then a gap of ``lost`` steps
            filler.fill(step, np.zeros(n_channels))
            step += 1
        step += lost
    filler.fill(step, np.zeros(n_channels))   # closes the last gap
