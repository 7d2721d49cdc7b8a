"""Whole-numerical reference simulations (seed 6.3.4), a DTM specimen model and offline RTHS.

Reference model (building + ``n`` DTMs on the interface DOF, all numerical)::

    [M + n m_f e e^T   0    ] [u''  ]   [C + n c_d e e^T  -n c_d e] [u' ]
    [0                 n m_d] [u_d''] + [-n c_d e^T        n c_d  ] [u_d'] + (same with k)
        = -[M Gamma + n m_f e; n m_d] a_g

``u_d`` is the DTM moving mass's displacement relative to the ground, ``e``
selects the interface DOF, ``m_f`` the DTM frame mass (seed 5.1, 250 lbm),
``m_d, c_d, k_d`` Table 4 (seed eq. 44-46).  Every mass is excited by the
ground.  Metrics of tables 6-8: max and RMS of the 2nd-floor displacement
(relative to the ground) and their reduction against the uncontrolled
building (no DTMs, no frames).

:class:`DTMSpecimen` stands in for the lab: given the table displacement of
each step it returns the measured force ``m_f a_table + m_d a_moving_mass``
(the project's convention, see :mod:`.substructure`); :class:`StrokeSpecimen` does
the same for a device between the table and the ground (the MR damper).  :func:`coupled_rths`
runs a :class:`.substructure.NumericalSubstructure` against any such callable
exactly as the ROS lock-step loop does.
"""

import numpy as np

from .dtm import FRAME_MASS_KG, SEED_CONFIGURATION, DTMParameters, dtm_configuration
from .integrators import make_integrator
from .model import LinearModel

INCH = 0.0254


def coupled_model(model: LinearModel, dtm: DTMParameters, n_dtm=5, frame_mass_kg=FRAME_MASS_KG,
                  dof=None) -> LinearModel:
    """Return ``model`` with ``n_dtm`` DTMs (moving mass + frame) attached at ``dof``."""
    dof = model.interface_dofs[0] if dof is None else dof
    n = model.n
    M = np.zeros((n + 1, n + 1))
    C = np.zeros_like(M)
    K = np.zeros_like(M)
    M[:n, :n], C[:n, :n], K[:n, :n] = model.M, model.C, model.K
    M[dof, dof] += n_dtm * frame_mass_kg
    M[n, n] = n_dtm * dtm.m_d
    for mat, val in ((C, n_dtm * dtm.c_d), (K, n_dtm * dtm.k_d)):
        mat[dof, dof] += val
        mat[n, n] += val
        mat[dof, n] -= val
        mat[n, dof] -= val
    gamma = np.concatenate([model.gamma, [1.0]])
    return LinearModel(M, C, K, gamma, [dof], model.output_dof, model.name + '+dtm',
                       list(model.dof_names) + ['dtm'],
                       external_force=np.concatenate([model.external_force, [0.0]]),
                       external_force_time=model.external_force_time)


def integrate_model(model: LinearModel, ag, dt, integrator='cr', rho_inf=0.5):
    """Integrate ``M u'' + C u' + K u = -M Gamma a_g + F s(t)`` from rest; return (d, a)."""
    ag = np.asarray(ag, dtype=float)
    integ = make_integrator(integrator, model.M, model.C, model.K, dt, rho_inf)
    mg = model.M @ model.gamma
    n = ag.size
    # external force F s(t_k) [N] per step (model.load's term), zero when the model has none
    force = (np.outer(model.external_force_scale(np.arange(n) * dt), model.external_force)
             if model.has_external_force else np.zeros((n, model.n)))
    d = np.zeros((n, model.n))
    a = np.zeros((n, model.n))
    integ.set_state(np.zeros(model.n), np.zeros(model.n), p=-mg * ag[0] + force[0])
    a[0] = integ.a
    for k in range(1, n):
        p = -mg * ag[k] + force[k]
        integ.predict(p)
        integ.correct(p, np.zeros(model.n))
        d[k] = integ.d
        a[k] = integ.a
    return d, a


def metrics(disp, reference=None):
    """Table 6-8 metrics of a displacement history [m]; reductions [%] against ``reference``."""
    disp = np.asarray(disp, dtype=float)
    out = {'max_disp_m': float(np.max(np.abs(disp))),
           'rms_disp_m': float(np.sqrt(np.mean(disp ** 2)))}
    out['max_disp_in'] = out['max_disp_m'] / INCH
    out['rms_disp_in'] = out['rms_disp_m'] / INCH
    if reference is not None:
        out['max_reduction_pct'] = 100 * (1 - out['max_disp_m'] / reference['max_disp_m'])
        out['rms_reduction_pct'] = 100 * (1 - out['rms_disp_m'] / reference['rms_disp_m'])
    return out


def simulate_uncontrolled(model: LinearModel, ag, dt, integrator='cr'):
    """Simulate the building alone: ``{'time', 'disp', 'accel_abs', 'metrics'}`` of its output."""
    d, a = integrate_model(model, ag, dt, integrator)
    out = model.output_dof
    disp = d[:, out]
    return {'time': np.arange(len(ag)) * dt, 'disp': disp,
            'accel_abs': a[:, out] + model.gamma[out] * np.asarray(ag), 'metrics': metrics(disp)}


def simulate_reference(model: LinearModel, ag, dt, damper=SEED_CONFIGURATION, n_dtm=5,
                       frame_mass_kg=FRAME_MASS_KG, integrator='cr', uncontrolled=None):
    """Simulate the building + ``n_dtm`` DTMs (Table 4 ``damper``), all numerical (seed 6.3.4).

    Returns ``{'time', 'disp', 'accel_abs', 'dtm_stroke', 'metrics'}``; the
    metrics include reductions against ``uncontrolled`` (computed if None).
    """
    dtm = damper if isinstance(damper, DTMParameters) else dtm_configuration(damper)
    full = coupled_model(model, dtm, n_dtm, frame_mass_kg)
    d, a = integrate_model(full, ag, dt, integrator)
    out = model.output_dof
    if uncontrolled is None:
        uncontrolled = simulate_uncontrolled(model, ag, dt, integrator)
    disp = d[:, out]
    return {'time': np.arange(len(ag)) * dt, 'disp': disp,
            'accel_abs': a[:, out] + model.gamma[out] * np.asarray(ag),
            'dtm_stroke': d[:, -1] - d[:, full.interface_dofs[0]],
            'metrics': metrics(disp, uncontrolled['metrics'])}


class DTMSpecimen:
    """A DTM (Table 4) on its frame on a perfect shake table: table displacement -> measured force.

    Table velocity and acceleration are backward differences of the commanded
    displacements (what a lab derives from its LVDT); the moving mass obeys
    seed eq. 46, ``m_d z'' + c_d z' + k_d z = -m_d a_table`` (``z`` relative to
    the frame), integrated exactly for piecewise-constant ``a_table``.  Returns
    ``[m_f a_table + m_d (a_table + z'')]`` [N].

    Effects a model update may add (e.g. ``updated_model.yaml`` of the
    discrepancy workflow): ``force(z, z')`` [N], an extra force on the moving
    mass (friction, stiffness errors, ...), and ``mass_error`` [kg]::

        (m_d + dm) (z'' + a_table) + c_d z' + k_d z + force(z, z') = 0

    The measured force is then ``m_f a_table - (c_d z' + k_d z + force)``.
    With ``force`` the sample is split into ``substeps`` exact zero-order-hold
    sub-steps with the force held per sub-step (as the simulated plant does
    for its Coulomb friction, rths_actuator_bridge.simulated).
    """

    def __init__(self, dtm=SEED_CONFIGURATION, dt=1 / 1024, frame_mass_kg=FRAME_MASS_KG, force=None,
                 mass_error=0.0, substeps=16):
        """Store the parameters and the exact one-step matrices (scipy expm)."""
        self.dtm = dtm if isinstance(dtm, DTMParameters) else dtm_configuration(dtm)
        self.dt = float(dt)
        self.frame_mass = float(frame_mass_kg)
        self.force = force
        self.substeps = int(substeps) if force is not None else 1
        if self.substeps < 1:
            raise ValueError(f'substeps must be >= 1, got {substeps}')
        A, B = self.dtm.state_space(mass_error)   # inputs: a_table, force
        big = np.zeros((4, 4))
        big[:2, :2], big[:2, 2:] = A, B
        # lazy: start-up cost: scipy.linalg (~0.4 s) for every `rths` command (the CLI lists this)
        from scipy.linalg import expm

        E = expm(big * self.dt / self.substeps)
        self._Ad, self._Bd = E[:2, :2], E[:2, 2:]
        self._x = [None, None]
        self._z = np.zeros(2)

    def __call__(self, table_disp):
        """Return the measured force [N] for this step's table displacement [m]."""
        x = float(np.asarray(table_disp).reshape(-1)[0])
        x1, x2 = self._x
        x1 = x if x1 is None else x1
        x2 = x1 if x2 is None else x2
        acc = (x - 2 * x1 + x2) / self.dt ** 2
        self._x = [x, x1]
        f = 0.0
        for _ in range(self.substeps):
            if self.force is not None:
                f = self.force(self._z[0], self._z[1])
            self._z = self._Ad @ self._z + self._Bd @ np.array([acc, f])
        if self.force is not None:
            f = self.force(self._z[0], self._z[1])
        return np.array([self.frame_mass * acc - (self.dtm.frame_force(self._z[0], self._z[1])
                                                  + f)])


class StrokeSpecimen:
    """A device between the table and the ground on a perfect actuator: stroke in, force out.

    ``device`` has ``reset()``, ``advance(x0, v0, x1, v1, h)`` (its states over ``h``
    seconds, stroke and velocity linear in between) and ``force()`` [N].  The velocity
    at step k is ``(3 x_k - 4 x_{k-1} + x_{k-2}) / (2 dt)``; each loop step is split into
    ``substeps`` sub-steps.
    """

    def __init__(self, device, dt, substeps=8):
        """Set the device, the loop step [s] and its sub-steps."""
        self.dt = float(dt)
        self.substeps = int(substeps)
        if self.substeps < 1:
            raise ValueError(f'substeps must be >= 1, got {substeps}')
        self.device = device
        self._x = [0.0, 0.0]
        self._v = 0.0

    def __call__(self, stroke):
        """Return ``[force]`` [N] for this step's stroke [m]."""
        x = float(np.asarray(stroke).reshape(-1)[0])
        x1, x2 = self._x
        v = (3.0 * x - 4.0 * x1 + x2) / (2.0 * self.dt)
        h = self.dt / self.substeps
        xa, va = x1, self._v
        for j in range(1, self.substeps + 1):
            s = j / self.substeps
            xb, vb = x1 + s * (x - x1), self._v + s * (v - self._v)
            self.device.advance(xa, va, xb, vb, h)
            xa, va = xb, vb
        self._x = [x, x1]
        self._v = v
        return np.array([self.device.force()])


def coupled_rths(substructure, specimen):
    """Run the lock-step RTHS loop offline: ``force = specimen(command)`` every step.

    Returns ``substructure.history()``; the ROS run with the same substructure
    and a perfect plant must equal it to round-off.
    """
    command = substructure.first_displacement()
    while not substructure.done():
        command = substructure.advance(specimen(command))
    return substructure.history()


def relative_rms_error(x, ref):
    """Relative RMS error [%] of ``x`` with respect to ``ref`` (seed Table 9 metric)."""
    x, ref = np.asarray(x, dtype=float), np.asarray(ref, dtype=float)
    return float(100 * np.sqrt(np.mean((x - ref) ** 2) / np.mean(ref ** 2)))
