"""Rigid-coupler kinematics: actuator strokes <-> interface DOFs (translation x, rotation theta).

Several actuators drive one interface node through a rigid coupler.  Actuator ``i`` is
attached to the coupler at an arm of length ``d_i`` from the node, at angle ``alpha_i``
from the actuators' axis (x).  When the node translates by ``x`` and the coupler rotates
by ``theta`` (counter-clockwise, rad), the attachment point's coordinate along the axis
moves by ``x + d_i (cos(theta + alpha_i) - cos(alpha_i))``: that is the stroke the actuator
must impose (its axial direction assumed fixed, as in the maRTHS benchmark's coupler).

* :meth:`Coupler.strokes`: the exact (large-rotation) forward map, for any number of
  actuators and arrays of samples;
* :meth:`Coupler.jacobian`: its linearisation at ``theta = 0``, the rows ``[1, -d_i sin a_i]``
  (``-d_i sin a_i`` is minus the arm's lateral offset ``y_i``);
* :meth:`Coupler.dofs`: the inverse (strokes -> x, theta), exact for two or more actuators:
  the least-squares solution of the linear map refined by Gauss-Newton on the exact one;
* :meth:`Coupler.interface_forces`: the actuators' axial forces (load cells) as the force
  and moment they apply at the node, ``J(theta)^T f`` by virtual work, with
  ``J(theta)`` the exact map's Jacobian (rows ``[1, -d_i sin(theta + alpha_i)]``).

Everything is in SI (m, rad).  A geometry that cannot resolve a rotation (all arms on the
actuators' axis) is refused when built.
"""

from dataclasses import dataclass
from functools import cached_property
import math

import numpy as np


@dataclass(frozen=True)
class Coupler:
    """Arms ``d`` [m] and angles ``alpha`` [rad] of the actuators' attachment points."""

    d: tuple
    alpha: tuple

    def __post_init__(self):
        """Check the geometry: same length, finite, arms > 0, rotation observable."""
        d = np.asarray(self.d, float)
        a = np.asarray(self.alpha, float)
        if d.ndim != 1 or d.shape != a.shape or d.size < 1:
            raise ValueError('coupler: d and alpha must be lists of the same length (one per '
                             'actuator)')
        if not (np.all(np.isfinite(d)) and np.all(np.isfinite(a)) and np.all(d > 0)):
            raise ValueError('coupler: every arm d must be finite and > 0 m and every angle '
                             'alpha finite (rad)')
        if d.size >= 2 and np.linalg.matrix_rank(self._lin(d, a)) < 2:
            raise ValueError('coupler: the arms give no independent rotation (all lateral '
                             'offsets d*sin(alpha) equal); fix the geometry')

    @classmethod
    def from_offsets(cls, xy):
        """Coupler of attachment points at offsets ``(x_i, y_i)`` [m] from the node."""
        xy = np.asarray(xy, float).reshape(-1, 2)
        return cls(tuple(np.hypot(xy[:, 0], xy[:, 1])),
                   tuple(np.arctan2(xy[:, 1], xy[:, 0])))

    @property
    def n(self) -> int:
        """Return the number of actuators."""
        return len(self.d)

    @staticmethod
    def _lin(d, a):
        return np.column_stack([np.ones_like(d), -d * np.sin(a)])

    @cached_property
    def _pinv(self) -> np.ndarray:
        return np.linalg.pinv(self.jacobian())

    def jacobian(self) -> np.ndarray:
        """``n x 2`` linear map ``[x, theta] -> strokes`` at ``theta = 0``."""
        return self._lin(np.asarray(self.d, float), np.asarray(self.alpha, float))

    def strokes(self, x, theta, linear: bool = False) -> np.ndarray:
        """Strokes [m], shape ``(n,) + shape(x)``; ``linear`` uses :meth:`jacobian`."""
        x = np.asarray(x, float)
        theta = np.asarray(theta, float)
        d = np.asarray(self.d, float).reshape((-1,) + (1,) * x.ndim)
        a = np.asarray(self.alpha, float).reshape(d.shape)
        if linear:
            return x - d * np.sin(a) * theta
        return x + d * (np.cos(theta + a) - np.cos(a))

    def dofs(self, strokes, linear: bool = False, iterations: int = 6):
        """``(x, theta)`` of the strokes (shape ``(n, ...)``), least squares for n > 2."""
        s = np.asarray(strokes, float)
        if s.shape[0] != self.n:
            raise ValueError(f'coupler: {s.shape[0]} strokes given for {self.n} actuators')
        if self.n < 2:
            raise ValueError('coupler: one actuator cannot resolve x and theta')
        if s.ndim == 1 and not linear:
            key = (tuple(s.tolist()), iterations)
            memo = self.__dict__.get('_memo')   # the bridge asks three times per reading
            if memo is None or memo[0] != key:
                memo = self.__dict__['_memo'] = (key, self._dofs_one(list(key[0]), iterations))
            return memo[1][0].copy(), memo[1][1].copy()
        flat = s.reshape(self.n, -1)
        q = self._pinv @ flat
        if not linear:
            d = np.asarray(self.d, float)[:, None]
            a = np.asarray(self.alpha, float)[:, None]
            for _ in range(iterations):
                x, th = q
                r = x + d * (np.cos(th + a) - np.cos(a)) - flat
                j_th = -d * np.sin(th + a)
                # Gauss-Newton per sample: J = [1, j_th] per row.
                s1, s2 = j_th.sum(0), (j_th * j_th).sum(0)
                r0, r1 = r.sum(0), (j_th * r).sum(0)
                det = self.n * s2 - s1 * s1
                q = q - np.array([(s2 * r0 - s1 * r1) / det, (self.n * r1 - s1 * r0) / det])
        shape = s.shape[1:]
        return q[0].reshape(shape), q[1].reshape(shape)

    @cached_property
    def _one(self) -> tuple:
        """Python floats of the geometry for :meth:`_dofs_one`: pinv rows, d, alpha, cos alpha."""
        return (tuple(tuple(float(v) for v in row) for row in self._pinv),
                tuple(float(v) for v in self.d), tuple(float(v) for v in self.alpha),
                tuple(math.cos(float(v)) for v in self.alpha))

    def _dofs_one(self, s: list, iterations: int):
        """:meth:`dofs` of one sample in Python floats (the bridge's per-step call).

        The same steps as the array path (same values to round-off) at a few microseconds
        instead of ~100 (numpy's per-call cost on two-element arrays).
        """
        (p0, p1), d, a, cos_a = self._one
        n = len(d)
        x = sum(p0[i] * s[i] for i in range(n))
        th = sum(p1[i] * s[i] for i in range(n))
        for _ in range(iterations):
            s1 = s2 = r0 = r1 = 0.0
            for i in range(n):
                r = x + d[i] * (math.cos(th + a[i]) - cos_a[i]) - s[i]
                j = -d[i] * math.sin(th + a[i])
                s1 += j
                s2 += j * j
                r0 += r
                r1 += j * r
            det = n * s2 - s1 * s1
            x, th = x - (s2 * r0 - s1 * r1) / det, th - (n * r1 - s1 * r0) / det
        return np.asarray(x), np.asarray(th)

    def interface_forces(self, forces, theta=0.0):
        """``(F_x [N], M [N m])`` at the node of the axial ``forces`` (shape ``(n, ...)``)."""
        f = np.asarray(forces, float)
        if f.shape[0] != self.n:
            raise ValueError(f'coupler: {f.shape[0]} forces given for {self.n} actuators')
        if f.ndim == 1 and np.ndim(theta) == 0:      # one reading: Python floats
            _, d, a, _ = self._one
            th = float(theta)
            fl = f.tolist()
            return (np.float64(sum(fl)),
                    np.float64(sum(-d[i] * math.sin(th + a[i]) * fl[i] for i in range(self.n))))
        theta = np.asarray(theta, float)
        d = np.asarray(self.d, float).reshape((-1,) + (1,) * (f.ndim - 1))
        a = np.asarray(self.alpha, float).reshape(d.shape)
        return f.sum(axis=0), (-d * np.sin(theta + a) * f).sum(axis=0)

    def axial_forces(self, force, moment, theta=0.0) -> np.ndarray:
        """Return the axial forces [N] that apply ``force`` [N] and ``moment`` [N m] at the node.

        The inverse of :meth:`interface_forces` at rotation ``theta`` (two actuators: exact;
        more: the least-norm solution).
        """
        _, d, a, _ = self._one
        th = float(theta)
        if self.n == 2:     # one 2 x 2 solve in Python floats (the rig's per-step call)
            j0, j1 = -d[0] * math.sin(th + a[0]), -d[1] * math.sin(th + a[1])
            det = j1 - j0
            return np.array([(j1 * force - moment) / det, (moment - j0 * force) / det])
        jac = np.column_stack([np.ones(self.n), -np.asarray(d) * np.sin(th + np.asarray(a))])
        return np.linalg.pinv(jac.T) @ np.array([force, moment], float)
