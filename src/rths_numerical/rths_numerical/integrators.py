"""Direct integration of ``M a + C v + K d + r = p`` for RTHS, with an explicit displacement.

All three classes share one RTHS cycle (seed eq. 25: the numerical substructure
computes the interface displacement, the lab returns the restoring force)::

    d_next = integ.predict()          # displacement of step k+1, known BEFORE r_{k+1}
    ... send d_next to the specimen, measure r_{k+1} ...
    a, v = integ.correct(p_next, r_next)

``p`` is the external load vector (ground motion ``-M Gamma a_g`` plus forces),
``r`` the measured restoring-force vector (zero except at interface DOFs).

Chen-Ricles, CR (Chen & Ricles 2008, J. Struct. Eng. 134(8))::

    v_{k+1} = v_k + dt alpha_1 a_k
    d_{k+1} = d_k + dt v_k + dt^2 alpha_2 a_k
    alpha_1 = alpha_2 = 4 (4 M + 2 dt C + dt^2 K)^-1 M
    M a_{k+1} = p_{k+1} - C v_{k+1} - K d_{k+1} - r_{k+1}

Explicit in displacement AND velocity; for linear systems it has the
characteristics of the trapezoidal rule: spectral radius 1 (no numerical
damping) and period elongation ``T'/T = (Omega/2) / atan(Omega/2)``,
``Omega = omega dt``; unconditionally stable.

Kolay-Ricles KR-alpha (Kolay & Ricles 2014, Earthq. Eng. Struct. Dyn. 43(9))::

    alpha_m = (2 rho - 1) / (rho + 1), alpha_f = rho / (rho + 1)
    gamma = 1/2 - alpha_m + alpha_f, beta = (1 - alpha_m + alpha_f)^2 / 4
    D = M + gamma dt C + beta dt^2 K
    alpha_1 = D^-1 M, alpha_2 = (1/2 + gamma) D^-1 M,
    alpha_3 = D^-1 (alpha_m M + alpha_f (gamma dt C + beta dt^2 K))
    v_{k+1} = v_k + dt alpha_1 a_k,  d_{k+1} = d_k + dt v_k + dt^2 alpha_2 a_k
    M [(I - alpha_3) a_{k+1} + alpha_3 a_k] + C v_{k+1-af} + K d_{k+1-af} + r_{k+1-af}
        = p_{k+1-af},    x_{k+1-af} = (1 - alpha_f) x_{k+1} + alpha_f x_k

For linear systems its amplification matrix has the eigenvalues of the
generalized-alpha method (Chung & Hulbert 1993) with the same ``rho_inf``:
spectral radius ``rho_inf`` as ``Omega -> inf``, second-order accuracy,
unconditional stability; ``rho_inf = 1`` is non-dissipative.  The tests compare
the amplification matrices of both methods (see :func:`amplification_matrix`).

Newmark average acceleration (gamma = 1/2, beta = 1/4), RTHS form: the
displacement of step k+1 is solved from the Newmark effective-stiffness
equation with the restoring force estimated by the last measured one
(``r_{k+1} ~ r_k``; exact when ``r`` is zero or constant), then the
acceleration of step k+1 satisfies equilibrium with the measured ``r_{k+1}``::

    (M + dt/2 C + dt^2/4 K) d_{k+1} = p_{k+1} - r_k + M (d_k + dt v_k + dt^2/4 a_k) 4/dt^2 ...
    (M + dt/2 C) a_{k+1} = p_{k+1} - r_{k+1} - K d_{k+1} - C (v_k + dt/2 a_k)
    v_{k+1} = v_k + dt/2 (a_k + a_{k+1})

Without a restoring force it is the classical trapezoidal rule: spectral radius
1, period elongation ``(Omega/2)/atan(Omega/2)`` as for CR.

Central difference (explicit, the pairing of OpenSees' ``CentralDifference``)::

    (M/dt^2 + C/(2 dt)) d_{k+1} = p_k - r_k - (K - 2 M/dt^2) d_k - (M/dt^2 - C/(2 dt)) d_{k-1}
    a_k = (d_{k+1} - 2 d_k + d_{k-1}) / dt^2,   v_k = (d_{k+1} - d_{k-1}) / (2 dt)

Equilibrium at step k gives the displacement of step k+1: the force measured
at step k pairs with the displacement sent at step k+1, exactly the RTHS step.
Conditionally stable: ``omega_max dt < 2`` (checked, :class:`CentralDifference`);
second-order accurate, period shortening instead of CR's elongation.

State matrices are precomputed, so each step costs two dense mat-vec products.
"""

import numpy as np
import scipy.linalg as sla

INTEGRATORS = ('cr', 'kr_alpha', 'newmark', 'central_difference')


class _Integrator:
    """Shared state (d, v, a) and the precomputed equilibrium operators."""

    name = ''
    #: Whether :meth:`predict` reads ``p_next`` (the explicit CR/KR-alpha do not).
    predict_uses_load = True

    def __init__(self, M, C, K, dt):
        self.M = np.atleast_2d(np.asarray(M, dtype=float))
        self.C = np.atleast_2d(np.asarray(C, dtype=float))
        self.K = np.atleast_2d(np.asarray(K, dtype=float))
        n = self.M.shape[0]
        for label, mat in (('M', self.M), ('C', self.C), ('K', self.K)):
            if mat.shape != (n, n):
                raise ValueError(f'{label} has shape {mat.shape}; expected ({n}, {n}) like M')
        if not dt > 0:
            raise ValueError(f'time step dt = {dt} s must be positive')
        self.n = n
        self.dt = float(dt)
        self.d = np.zeros(n)
        self.v = np.zeros(n)
        self.a = np.zeros(n)
        self.r = np.zeros(n)
        self._d_next = None

    def set_state(self, d, v, a=None, p=None, r=None):
        """Set the state of step k; ``a`` defaults to equilibrium with ``p`` and ``r``."""
        self.d = np.array(d, dtype=float).reshape(self.n)
        self.v = np.array(v, dtype=float).reshape(self.n)
        self.r = np.zeros(self.n) if r is None else np.array(r, dtype=float).reshape(self.n)
        p = np.zeros(self.n) if p is None else np.array(p, dtype=float).reshape(self.n)
        self._p = p.copy()
        self._p_last = p.copy()
        if a is None:
            a = np.linalg.solve(self.M, p - self.r - self.C @ self.v - self.K @ self.d)
        self.a = np.array(a, dtype=float).reshape(self.n)
        self._d_next = None

    def predict(self, p_next=None):
        """Return the displacement ``d_{k+1}`` [m] (needs only the state of step k)."""
        raise NotImplementedError

    def correct(self, p_next, r_next):
        """Finish step k+1 with load ``p_{k+1}`` and restoring force ``r_{k+1}``; return (a, v)."""
        raise NotImplementedError

    def step(self, p_next, r_next=None):
        """Advance one purely numerical step, ``r`` given or zero; return ``d_{k+1}``."""
        d = self.predict(p_next)
        self.correct(p_next, np.zeros(self.n) if r_next is None else r_next)
        return d


class _ExplicitAlpha(_Integrator):
    """CR and KR-alpha: explicit v, d from a_k; equilibrium weighted by alpha_f, alpha_3."""

    predict_uses_load = False

    def _build(self, a1, a2_factor, a3, alpha_f):
        """Precompute the one-step operators (``alpha_2 = a2_factor * alpha_1``)."""
        n, dt = self.n, self.dt
        eye = np.eye(n)
        self.alpha_1, self.alpha_2, self.alpha_3, self.alpha_f = a1, a2_factor * a1, a3, alpha_f
        self._a1 = np.ascontiguousarray(a1)
        self._c2 = a2_factor * dt * dt
        # M (I - a3) a_{k+1} + M a3 a_k + g (C v_{k+1} + K d_{k+1}) + af (C v_k + K d_k)
        #     = g (p - r)_{k+1} + af (p - r)_k,   g = 1 - af
        # with v_{k+1} = v_k + dt A1 a_k and d_{k+1} = d_k + dt v_k + c2 A1 a_k:
        # a_{k+1} = G [(p - r)_{k+1}, (p - r)_k, d_k, v_k, a_k]
        inv = np.linalg.inv(self.M @ (eye - a3))
        af, g = alpha_f, 1.0 - alpha_f
        K, C = self.K, self.C
        s_d = -inv @ K
        s_v = -inv @ (g * dt * K + C)
        s_a = -inv @ (g * (self._c2 * K + dt * C) @ a1 + self.M @ a3)
        blocks = [g * inv] + ([af * inv] if af else []) + [s_d, s_v, s_a]
        self._G = np.ascontiguousarray(np.hstack(blocks))
        self._buf = np.zeros(len(blocks) * n)
        self._p = np.zeros(n)

    def predict(self, p_next=None):
        """Return ``d_{k+1}`` [m]; explicit (``p_next`` is ignored)."""
        w = self._a1 @ self.a
        self._v_next = self.v + self.dt * w
        self._d_next = self.d + self.dt * self.v + self._c2 * w
        return self._d_next

    def correct(self, p_next, r_next):
        """Acceleration and velocity of step k+1 from equilibrium; return (a, v)."""
        if self._d_next is None:
            self.predict()
        p_next = np.asarray(p_next, dtype=float)
        r_next = np.asarray(r_next, dtype=float)
        n = self.n
        b = self._buf            # filled in place (slices, not stored views: copies stay valid)
        np.subtract(p_next, r_next, out=b[:n])
        i = n
        if self.alpha_f:
            np.subtract(self._p, self.r, out=b[n:2 * n])
            i = 2 * n
        b[i:i + n], b[i + n:i + 2 * n], b[i + 2 * n:] = self.d, self.v, self.a
        self.a = self._G @ b
        self.d, self.v = self._d_next, self._v_next
        self._p = p_next
        self.r = r_next
        self._d_next = None
        return self.a, self.v


class ChenRicles(_ExplicitAlpha):
    """Chen-Ricles (CR) explicit unconditionally stable algorithm; see the module docstring."""

    name = 'cr'

    def __init__(self, M, C, K, dt):
        super().__init__(M, C, K, dt)
        dt = self.dt
        alpha = 4.0 * np.linalg.solve(4.0 * self.M + 2.0 * dt * self.C + dt * dt * self.K, self.M)
        self._build(alpha, 1.0, np.zeros((self.n, self.n)), 0.0)


class KRAlpha(_ExplicitAlpha):
    """Kolay-Ricles KR-alpha explicit algorithm with spectral radius ``rho_inf`` in [0, 1]."""

    name = 'kr_alpha'

    def __init__(self, M, C, K, dt, rho_inf=0.5):
        super().__init__(M, C, K, dt)
        rho = float(rho_inf)
        if not 0.0 <= rho <= 1.0:
            raise ValueError(f'rho_inf = {rho_inf} must lie in [0, 1] (1: no numerical damping)')
        self.rho_inf = rho
        am = (2.0 * rho - 1.0) / (rho + 1.0)
        af = rho / (rho + 1.0)
        gamma = 0.5 - am + af
        beta = 0.25 * (1.0 - am + af) ** 2
        dt = self.dt
        stiff = gamma * dt * self.C + beta * dt * dt * self.K
        dmat = self.M + stiff
        base = np.linalg.solve(dmat, self.M)
        a3 = np.linalg.solve(dmat, am * self.M + af * stiff)
        self.alpha_m, self.gamma, self.beta = am, gamma, beta
        self._build(base, 0.5 + gamma, a3, af)


class NewmarkAverage(_Integrator):
    """Newmark average acceleration (trapezoidal rule) with an RTHS displacement predictor."""

    name = 'newmark'

    def __init__(self, M, C, K, dt):
        super().__init__(M, C, K, dt)
        dt = self.dt
        M, C, K = self.M, self.C, self.K
        keff = 4.0 / dt ** 2 * M + 2.0 / dt * C + K
        self._keff = sla.lu_factor(keff)
        kinv = np.linalg.inv(keff)
        self._kinv = kinv
        # d_{k+1} = kinv (p_{k+1} - r_k + M(4/dt^2 d + 4/dt v + a) + C(2/dt d + v))
        self._Pd = kinv @ np.hstack([4.0 / dt ** 2 * M + 2.0 / dt * C, 4.0 / dt * M + C, M])
        ainv = np.linalg.inv(M + 0.5 * dt * C)
        self._ainv = ainv
        self._Qa = np.hstack([ainv @ K, ainv @ C, 0.5 * dt * ainv @ C])
        self._p_last = np.zeros(self.n)

    def predict(self, p_next=None):
        """Return ``d_{k+1}`` [m]; uses ``p_next`` if given, else the last load ``p_k``."""
        p = self._p_last if p_next is None else np.asarray(p_next, dtype=float)
        self._d_next = self._kinv @ (p - self.r) + self._Pd @ np.concatenate(
            [self.d, self.v, self.a])
        return self._d_next

    def correct(self, p_next, r_next):
        """Acceleration from equilibrium at the predicted displacement; return (a, v)."""
        if self._d_next is None:
            self.predict(p_next)
        p_next = np.asarray(p_next, dtype=float)
        r_next = np.asarray(r_next, dtype=float)
        a = self._ainv @ (p_next - r_next) - self._Qa @ np.concatenate(
            [self._d_next, self.v, self.a])
        self.v = self.v + 0.5 * self.dt * (self.a + a)
        self.d, self.a = self._d_next, a
        self.r = r_next.copy()
        self._p_last = p_next.copy()
        self._d_next = None
        return self.a, self.v


class CentralDifference(_Integrator):
    """Explicit central difference; ``d_{k+1}`` is known once step k's force is (module doc)."""

    name = 'central_difference'
    predict_uses_load = False

    def __init__(self, M, C, K, dt):
        super().__init__(M, C, K, dt)
        check_central_difference_step(self.M, self.K, self.dt)
        dt = self.dt
        M, C, K = self.M, self.C, self.K
        ainv = np.linalg.inv(M / dt ** 2 + C / (2.0 * dt))
        # d_{k+1} = G [(p - r)_k, d_k, d_{k-1}]
        self._G = np.ascontiguousarray(np.hstack(
            [ainv, ainv @ (2.0 * M / dt ** 2 - K), -ainv @ (M / dt ** 2 - C / (2.0 * dt))]))
        self._buf = np.zeros(3 * self.n)
        self._d_prev = np.zeros(self.n)

    def _next(self, p, r):
        """Displacement of step k+1 from equilibrium at step k; sets ``a`` and ``v`` of step k."""
        n, b, dt = self.n, self._buf, self.dt
        np.subtract(p, r, out=b[:n])
        b[n:2 * n], b[2 * n:] = self.d, self._d_prev
        d_next = self._G @ b
        self.a = (d_next - 2.0 * self.d + self._d_prev) / dt ** 2
        self.v = (d_next - self._d_prev) / (2.0 * dt)
        self._d_next = d_next
        return d_next

    def set_state(self, d, v, a=None, p=None, r=None):
        """Set step k (``d_{k-1} = d - dt v + dt^2/2 a``) and compute ``d_{k+1}``."""
        super().set_state(d, v, a, p, r)
        dt = self.dt
        self._d_prev = self.d - dt * self.v + 0.5 * dt * dt * self.a
        self._next(self._p, self.r)

    def predict(self, p_next=None):
        """Return ``d_{k+1}`` [m], computed when step k finished (``p_next`` is ignored)."""
        if self._d_next is None:
            self._next(self._p, self.r)
        return self._d_next

    def correct(self, p_next, r_next):
        """Finish step k+1 with its load and restoring force; return (a, v) of step k+1."""
        d_next = self.predict()
        self._d_prev, self.d = self.d, d_next
        self._p = np.asarray(p_next, dtype=float)
        self.r = np.asarray(r_next, dtype=float)
        self._next(self._p, self.r)
        return self.a, self.v


def check_central_difference_step(M, K, dt):
    """Raise ValueError unless ``omega_max dt < 2`` (central-difference stability limit)."""
    w2 = sla.eigh(np.atleast_2d(K), np.atleast_2d(M), eigvals_only=True)
    w_max = float(np.sqrt(max(float(np.max(w2)), 0.0)))
    if w_max * dt >= 2.0:
        raise ValueError(
            f'integrator central_difference is unstable for this model at dt = {dt:g} s: the '
            f'highest mode ({w_max / (2 * np.pi):.1f} Hz) needs dt < {2.0 / w_max:.3g} s; raise '
            'fs_hz or use cr / kr_alpha (unconditionally stable)')


def make_integrator(name, M, C, K, dt, rho_inf=0.5):
    """Return the integrator ``name`` (one of :data:`INTEGRATORS`) built from M, C, K, dt."""
    if name == 'cr':
        return ChenRicles(M, C, K, dt)
    if name == 'kr_alpha':
        return KRAlpha(M, C, K, dt, rho_inf)
    if name == 'newmark':
        return NewmarkAverage(M, C, K, dt)
    if name == 'central_difference':
        return CentralDifference(M, C, K, dt)
    raise ValueError(f'integrator {name!r} is unknown; use one of {", ".join(INTEGRATORS)}')


def amplification_matrix(name, omega, dt, zeta=0.0, rho_inf=0.5):
    """Return the 3x3 one-step map of an SDOF (m = 1) on the state (d, v, a) of a free vibration.

    Built by stepping the integrator from unit states; with no load, the
    eigenvalues of this matrix give spectral radius, numerical damping and
    period elongation (:func:`numerical_properties`).
    """
    integ = make_integrator(name, [[1.0]], [[2 * zeta * omega]], [[omega ** 2]], dt, rho_inf)
    cols = []
    for unit in np.eye(3):
        integ.set_state([unit[0]], [unit[1]], [unit[2]])
        integ.step(np.zeros(1))
        cols.append([integ.d[0], integ.v[0], integ.a[0]])
    return np.array(cols).T


def generalized_alpha_matrix(omega, dt, rho_inf):
    """Return the 3x3 amplification matrix of the generalized-alpha method (Chung-Hulbert 1993).

    Used as the published reference for KR-alpha (same spectral properties).
    """
    rho = rho_inf
    am = (2 * rho - 1) / (rho + 1)
    af = rho / (rho + 1)
    gamma = 0.5 - am + af
    beta = 0.25 * (1 - am + af) ** 2
    w2 = omega ** 2
    # unknowns x = (d1, v1, a1); equations:
    # d1 - beta dt^2 a1 = d0 + dt v0 + (1/2 - beta) dt^2 a0
    # v1 - gamma dt a1 = v0 + (1 - gamma) dt a0
    # (1-am) a1 + (1-af) w2 d1 = -am a0 - af w2 d0
    A = np.array([[1.0, 0.0, -beta * dt ** 2],
                  [0.0, 1.0, -gamma * dt],
                  [(1 - af) * w2, 0.0, 1 - am]])
    B = np.array([[1.0, dt, (0.5 - beta) * dt ** 2],
                  [0.0, 1.0, (1 - gamma) * dt],
                  [-af * w2, 0.0, -am]])
    return np.linalg.solve(A, B)


def numerical_properties(amp, omega_dt):
    """Spectral radius, algorithmic damping ratio and period elongation of an amplification matrix.

    From the principal complex pair ``lambda = exp(Omega_bar (-xi +- i))``:
    ``xi = -ln|lambda| / arg(lambda)``, ``T_bar / T = Omega / arg(lambda)``
    (``Omega = omega dt``).  Returns ``(rho, xi, period_elongation)`` where the
    elongation is ``T_bar / T - 1``.
    """
    lam = np.linalg.eigvals(amp)
    rho = float(np.max(np.abs(lam)))
    cplx = lam[np.abs(lam.imag) > 1e-12]
    if cplx.size == 0:
        return rho, float('nan'), float('nan')
    principal = cplx[np.argmax(np.abs(cplx))]
    phase = abs(np.angle(principal))
    xi = -np.log(abs(principal)) / phase
    return rho, float(xi), float(omega_dt / phase - 1.0)
