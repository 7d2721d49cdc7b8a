"""The maRTHS benchmark's structures (Condori Uribe et al. 2023) and its numerical substructure.

Moved here from ``rths_bench.marths`` so that the numerical node can run the benchmark's
numerical substructure (``model: marths``) and the offline benchmark uses the same one.
Numbers: :mod:`rths_common.marths_data` (github.com/FermandoisLab/maRTHS-bmk-RoDeAC, MIT;
``build_reference.m``, ``build_numerical.m``, ``build_physical_ideal.m``).

* reference structure: the SAP2000 K and M of the whole 4-story frame, Rayleigh damping
  (:func:`reference_matrices`);
* numerical substructure: reference minus an ideal 3-DOF physical frame at the interface
  DOFs (x, and the rotations of the two beam ends) (:func:`numerical_matrices`);
* both integrated by Newmark's average acceleration at 1/fs (:class:`Newmark`, a batch of
  runs at once);
* :class:`MarthsSubstructure`: the numerical substructure behind the numerical node's step
  contract, in the actuators' coordinates: it takes the two load cells' axial forces [N]
  and gives the two target strokes [m] through the rig's coupler (:mod:`rths_common.coupler`).
"""

import numpy as np

from rths_common.marths_data import INCH, load_config, rig_coupler

from .stepping import SteppedSubstructure


def newmark_constants(dt: float, gamma: float = 0.5, beta: float = 0.25) -> tuple:
    """Return ``a0..a7`` of Newmark's method (average acceleration by default)."""
    return (1 / (beta * dt ** 2), gamma / (beta * dt), 1 / (beta * dt), 1 / (2 * beta) - 1,
            gamma / beta - 1, dt / 2 * (gamma / beta - 2), dt * (1 - gamma), gamma * dt)


def rayleigh(m, k, w_i: float, w_j: float, zeta: float):
    """``alpha M + beta K`` with damping ratio ``zeta`` at ``w_i`` and ``w_j`` [rad/s]."""
    alpha, beta = np.linalg.solve(0.5 * np.array([[1 / w_i, w_i], [1 / w_j, w_j]]),
                                  [zeta, zeta])
    return alpha * m + beta * k


def reference_matrices(cfg: dict):
    """``(K, M, C, l)`` of the reference frame; ``l`` the ground-motion influence vector."""
    ref = cfg['reference']
    k = np.asarray(ref['K'], float)
    m = np.diag(ref['M_diag'])
    c = rayleigh(m, k, *ref['rayleigh_rad_s'], ref['damping'])
    ell = np.zeros(k.shape[0])
    ell[np.asarray(ref['ground_dofs']) - 1] = 1.0
    return k, m, c, ell


def interface_dofs(cfg: dict) -> np.ndarray:
    """0-based DOFs of the physical part in the reference model: x, theta(node 2), theta."""
    d = cfg['reference']['dofs']
    return np.array([d['x'], d['theta_node2'], d['theta']]) - 1


def physical_ideal(cfg: dict):
    """``(K, M, C)`` of the ideal 3-DOF physical frame (x, two beam-end rotations)."""
    p = cfg['physical_ideal']
    lb, lc, e = p['Lb_m'], p['Lc_m'], p['E_pa']
    ic, ib = p['Ic_in4'] * INCH ** 4, p['Ib_in4'] * INCH ** 4
    ac, ab = p['Ac_in2'] * INCH ** 2, p['Ab_in2'] * INCH ** 2
    kc = 3 * e * ic
    k = np.array([[2 * kc / lc ** 3, -kc / lc ** 2, -kc / lc ** 2],
                  [-kc / lc ** 2, kc / lc + 4 * e * ib / lb, -2 * e * ib / lb],
                  [-kc / lc ** 2, -2 * e * ib / lb, kc / lc + 4 * e * ib / lb]])
    mass_b, mass_c = p['rho_kg_m3'] * ab * lb, p['rho_kg_m3'] * ac * lc
    rot = mass_b / 2 * lb ** 2 / 12 + mass_c / 2 * lc ** 2 / 12
    m = np.diag([mass_b + mass_c, rot, rot])
    w = np.sqrt(np.sort(np.real(np.linalg.eigvals(np.linalg.solve(m, k)))))
    c = rayleigh(m, k, w[0], w[2], p['damping'])
    return k, m, c


def numerical_matrices(cfg: dict):
    """``(K, M, C, l)`` of the numerical substructure: reference minus the ideal frame.

    As the benchmark does, only the translational mass of the ideal frame is removed.
    """
    k, m, c, ell = reference_matrices(cfg)
    kp, mp, cp = physical_ideal(cfg)
    idx = interface_dofs(cfg)
    k, m, c = k.copy(), m.copy(), c.copy()
    k[np.ix_(idx, idx)] -= kp
    c[np.ix_(idx, idx)] -= cp
    m[idx[0], idx[0]] -= mp[0, 0]
    return k, m, c, ell


class Newmark:
    """Batch of Newmark integrations of one linear structure (``M, C, K``, ground ``l``)."""

    def __init__(self, k, m, c, ell, dt, batch):
        """Prepare the effective stiffness for ``batch`` runs."""
        self.m, self.c, self.ell = m, c, ell
        self.a = newmark_constants(dt)
        self.kbar_inv = np.linalg.inv(k + self.a[0] * m + self.a[1] * c)
        n = k.shape[0]
        self.u = np.zeros((batch, n))
        self.v = np.zeros((batch, n))
        self.acc = np.zeros((batch, n))

    def step(self, ag: float, force=None):
        """Advance one step under ground acceleration ``ag`` and nodal forces (batch, n)."""
        a0, a1, a2, a3, a4, a5, a6, a7 = self.a
        u, v, acc = self.u, self.v, self.acc
        rhs = ((a0 * u + a2 * v + a3 * acc) @ self.m.T + (a1 * u + a4 * v + a5 * acc) @ self.c.T
               - ag * (self.m @ self.ell))
        if force is not None:
            rhs = rhs - force
        u1 = rhs @ self.kbar_inv.T
        acc1 = a0 * (u1 - u) - a2 * v - a3 * acc
        self.v = v + a6 * acc + a7 * acc1
        self.u, self.acc = u1, acc1
        return u1


def story_dofs(cfg: dict) -> dict:
    """0-based reference DOFs by name (``x``, ``theta``, ``x_2nd``, ``theta_2nd``, ...)."""
    return {k: v - 1 for k, v in cfg['reference']['dofs'].items()}


class MarthsSubstructure(SteppedSubstructure):
    """The maRTHS numerical substructure, stepped by the two actuators' axial forces.

    Step k (the offline loop of ``rths_bench.marths``, one sample later in the graph's
    convention: the measurement of step k answers command k): the axial forces become the
    force and moment at the interface node through the coupler at the commanded rotation
    (:meth:`rths_common.coupler.Coupler.interface_forces`), enter the Newmark step k + 1
    (ground acceleration ``ag[k + 1]``) on the interface DOFs x and theta, and the coupler
    turns the new (x, theta) into the target strokes of step k + 1.  Step 0's strokes come
    from the Newmark step 0 without specimen force (the rig at rest).

    The benchmark also feeds back the moment the physical frame puts on the far beam end
    (its third interface DOF); the load cells cannot measure it, so it is left out here.
    Its stiffness part is zero (the frame's slave rotations are condensed statically),
    only damping and inertia remain: ``test_marths.py`` bounds the effect on J1-J10.
    """

    backend = 'builtin'
    model = None

    def __init__(self, ground_accel, dt: float, motion=None, cfg: dict = None):
        """Set up the structure of ``cfg`` (default the benchmark's) under ``ground_accel``."""
        self.cfg = cfg or load_config()
        self.ag = np.asarray(ground_accel, dtype=float)
        self.dt = float(dt)
        self.n_steps = int(self.ag.size)
        if self.n_steps < 2:
            raise ValueError('the ground motion has fewer than 2 steps; check duration_s')
        self.motion = motion
        self.coupler = rig_coupler(self.cfg)
        self.n_interface = self.coupler.n
        self.dofs = story_dofs(self.cfg)
        self._matrices = numerical_matrices(self.cfg)
        self.reset()

    def reset(self):
        """Return to step 0 at rest."""
        self.num = Newmark(*self._matrices, self.dt, 1)
        n = self.num.u.shape[1]
        self._k = 0
        self._d = np.zeros((self.n_steps, n))
        self._cmd = np.zeros((self.n_steps, self.n_interface))
        self._force = np.zeros((self.n_steps, self.n_interface))
        self._cmd[0] = self._targets(self.num.step(self.ag[0])[0])
        self._d[0] = self.num.u[0]

    def _targets(self, u) -> np.ndarray:
        return self.coupler.strokes(u[self.dofs['x']], -u[self.dofs['theta']])

    def first_displacement(self) -> np.ndarray:
        """Target strokes of step 0 [m]."""
        return self._cmd[0].copy()

    def advance(self, measured_force) -> np.ndarray:
        """Finish step k with its axial forces [N]; return the target strokes of step k+1 [m]."""
        f = self.force_of(measured_force)
        k = self._k
        self._force[k] = f
        self._k = k + 1
        if k + 1 >= self.n_steps:
            return self._cmd[k].copy()
        u = self._d[k]
        fx, mom = self.coupler.interface_forces(f, -u[self.dofs['theta']])
        force = np.zeros((1, u.size))
        force[0, self.dofs['x']] = fx
        force[0, self.dofs['theta']] = -mom
        d = self.num.step(self.ag[k + 1], force)[0]
        self._d[k + 1] = d
        self._cmd[k + 1] = self._targets(d)
        return self._cmd[k + 1].copy()

    def done(self) -> bool:
        """Return True once ``n_steps`` steps are finished."""
        return self._k >= self.n_steps

    def state(self) -> dict:
        """Step count, time [s], target strokes and 3rd-story x [m] of the last finished step."""
        k = self._k
        if not k:
            return {'step': 0, 'time': float('nan'), 'interface_disp': np.full(2, np.nan),
                    'output_disp': float('nan')}
        return {'step': k, 'time': (k - 1) * self.dt, 'interface_disp': self._cmd[k - 1].copy(),
                'output_disp': float(self._d[k - 1, self.dofs['x_3rd']])}

    def history(self) -> dict:
        """Arrays of the finished steps (SI units); ``displacements``: every DOF of the model."""
        k = self._k
        d = self._d[:k]
        return {
            'time': np.arange(k) * self.dt,
            'ground_accel': self.ag[:k].copy(),
            'displacements': d.copy(),
            'output_disp': d[:, self.dofs['x_3rd']].copy(),
            'interface_disp': self._cmd[:k].copy(),
            'command': self._cmd[:k].copy(),
            'measured_force': self._force[:k].copy(),
            'x_num': d[:, self.dofs['x']].copy(),
            'theta_num': -d[:, self.dofs['theta']],
        }
