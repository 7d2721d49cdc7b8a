"""Compensator design: the FIR compensator (seed ch. 4) and the comparison compensators (ch. 2).

Plant (eq. 5-7): ``T(z^-1) = z^-d B*(z^-1)/A*(z^-1)``, ``B* = B+* B-*`` (stable / unstable
zeros, :func:`rths_compensator.identification.factor_zeros`).  Every design returns a
causal rational filter ``G = taps(z^-1)/denominator(z^-1)`` (a :class:`Design`).

FIR compensator (eq. 28-36)
    ``G_FIR = A*/B+* . H``, ``H = h1 + h2 z^-1 + ... + hn z^-(n-1)`` (eq. 28-29), so the
    compensated system is ``T_com = z^-d B-* H`` (eq. 30), LINEAR in h.  On a grid
    ``f_i`` (0 .. Nyquist) let ``M_i = e^{-j w_i d} B-*(f_i) [1, e^{-j w_i}, ...]``; then
    ``T_com(f_i) - 1 = M_i h - 1``.

    * LS / WLS (eq. 32): ``min_h sum_i w_i |M_i h - 1|^2`` (real/imaginary parts stacked:
      a linear least-squares problem), w_i = 1 everywhere (LS) or 1000 in the passband
      ``f <= fc`` and 1 in the stopband (WLS).
    * MM (eq. 33): ``min_h max_i |M_i h - 1|`` over the whole grid, posed as a linear
      programme (HiGHS): ``min t`` s.t. ``Re(e^{-j theta_m} (M_i h - 1)) <= t`` for
      ``theta_m = 2 pi m / S`` (a regular S-gon around the complex error; exact to
      ``1/cos(pi/S)``).
    * Constraints (all schemes).  Eq. 34 (unit DC gain) is imposed exactly as the linear
      equality ``B-*(1) sum(h) = 1``.  Eq. 35-36 (unit magnitude and zero phase over the
      passband, within a tolerance epsilon) are non-convex as written; we impose the
      convex per-frequency bound ``|T_com(f_i) - 1| <= epsilon`` for every passband
      point, which implies ``| |T_com| - 1 | <= epsilon`` and
      ``|arg T_com| <= asin(epsilon)``.  The disc is replaced by the inscribed S-gon
      ``Re(e^{-j theta_m}(M_i h - 1)) <= epsilon cos(pi/S)`` (linear inequalities,
      conservative by at most 1 - cos(pi/S)).
    * Solvers: LS/WLS first solve the equality-constrained problem (null-space least
      squares); if the passband bound already holds, that is the optimum of the convex
      problem.  Otherwise the inequality-constrained least squares (LSI) is solved exactly
      by the Lawson-Hanson reduction LSI -> least-distance programme -> non-negative
      least squares (``scipy.optimize.nnls``).  MM is one LP, solved by cutting planes
      (:func:`_minimax_lp`): a subset of its rows, then the violated rows of the full grid
      added until none is violated, each re-solve warm-started from the previous basis
      (the optimum of the same LP, 3-10x faster than handing HiGHS every row); the first
      relaxation has at least n real equations so that it bounds h.  No generic NLP is
      used.
    * The unknown is scaled by B-*(1) (``g = B-*(1) h``) so it is O(1).

Comparison compensators
    * inverse (eq. 2): ``G = a - (a - 1) z^-1``, ``a = tau + 1``, tau the delay in samples.
    * mff (eq. 4, Carrion & Spencer): ``G(s) = alpha^k prod(s - p_i)/prod(s - alpha p_i)``
      from the continuous-time poles (Table 1), discretised by the bilinear (Tustin) map.
    * npz (eq. 8): ``A*/(B+* B-*(1))``.
    * zpetc (eq. 12, modified causal ZPETC): ``A* B-(z^-1)/(B+* B-*(1)^2)`` with
      ``B-(z^-1)`` the coefficient-reversed B-* (``B-*(z) = z^q B-(z^-1)``).
    * zmetc (eq. 14): ``A*/(B+* B-(z^-1))``.
    Dead time d (if any) is not inverted by these; the FIR design includes it in T_com.
"""

import dataclasses
import time

import numpy as np
from scipy import linalg, optimize, signal

from .identification import ArxModel, factor_zeros
from .indicators import time_delay_ms
from .plants import actuator_poles
from .schemes import (
    DESIGN_DEFAULTS,
    SCHEMES,
    auto_schemes,
    default_fc_hz,
    designed,
    fir_schemes,
)

#: The FIR schemes and every designed scheme, from the registry (:mod:`.schemes`).
FIR_SCHEMES = fir_schemes()
ALL_SCHEMES = designed()

#: Default passband tolerance epsilon on |T_com - 1| (eq. 35-36); the seed gives no value.
DEFAULT_EPSILON = DESIGN_DEFAULTS['epsilon']


def default_grid(fs_hz: float) -> int:
    """Frequency points 0..Nyquist of the default LS/WLS design: at most 1 Hz apart."""
    return max(513, int(np.ceil(fs_hz / 2.0)) + 1)


def design_default(plant, **overrides) -> 'Design':
    """Design with :data:`DESIGN_DEFAULTS` (``overrides`` replace single entries).

    Without an ``fc_hz`` override (or with None) fc is :func:`.schemes.default_fc_hz` of the
    lag the FIR must predict (:func:`predicted_lag_s`) and the rate: the seed's 10 Hz,
    12.5 Hz from a lag of 7.5 ms at rates up to 1500 Hz.
    """
    opts = dict(DESIGN_DEFAULTS, **{k: v for k, v in overrides.items()
                                    if not (k == 'fc_hz' and v is None)})
    scheme = opts.pop('scheme')
    fs_hz = opts.pop('fs_hz', None)
    fs = plant_polynomials(plant, fs_hz)[3]
    lag = None
    if overrides.get('fc_hz') is None:
        lag = predicted_lag_s(plant, fs_hz)
        opts['fc_hz'] = default_fc_hz(lag, fs)
    if 'gain_weight' in SCHEMES.entry(scheme).options:      # the least-squares schemes
        opts.setdefault('n_grid', default_grid(fs))
    else:
        opts.pop('gain_weight', None)
    comp = design_fir(plant, fs_hz=None if isinstance(plant, ArxModel) else fs,
                      scheme=scheme, **opts)
    if lag is not None:     # fc chosen here: say from what
        comp.info['fc_default_lag_ms'] = 1e3 * lag
    return comp


@dataclasses.dataclass
class Design:
    """A designed compensator ``G = taps/denominator`` with its provenance."""

    scheme: str
    taps: np.ndarray
    denominator: np.ndarray
    fs_hz: float
    info: dict = dataclasses.field(default_factory=dict)

    def check(self) -> 'Design':
        """Raise ValueError if the filter is non-finite or unstable; return self."""
        if not (np.all(np.isfinite(self.taps)) and np.all(np.isfinite(self.denominator))):
            raise ValueError(f'{self.scheme} design has non-finite coefficients')
        if self.denominator.size > 1:
            rho = float(np.max(np.abs(np.roots(self.denominator))))
            if rho >= 1.0:
                raise ValueError(f'{self.scheme} design is unstable (pole modulus {rho:.6g})')
        return self


def plant_polynomials(plant, fs_hz: float = None):
    """Return ``(b_star, a_star, d, fs_hz)`` for an ArxModel or a ``(b, a)`` pair in z^-1."""
    if isinstance(plant, ArxModel):
        return plant.b.copy(), plant.a.copy(), plant.d, plant.fs_hz
    b, a = plant
    b = np.atleast_1d(np.asarray(b, dtype=float)).ravel()
    a = np.atleast_1d(np.asarray(a, dtype=float)).ravel()
    nz = np.flatnonzero(b)
    if nz.size == 0:
        raise ValueError('plant numerator is all zeros')
    d = int(nz[0])
    if fs_hz is None:
        raise ValueError('fs_hz is required when the plant is given as (b, a)')
    return b[d:] / a[0], a / a[0], d, float(fs_hz)


def predicted_lag_s(plant, fs_hz: float = None, zero_tol: float = 1.0) -> float:
    """Return the low-frequency lag [s] the FIR must predict: ``z^-d B-*(z) / B-*(1)``.

    The compensator inverts ``A* / B+*``; what is left to its FIR is the dead time and the
    unstable zeros ``B-*``, whose delay at low frequency is the centroid of the unit-gain
    ``B-*`` coefficients (its group delay at DC).  The dead time ``d`` alone understates it
    when a fitted model spreads part of the delay over unstable zeros: on the held-out lab 7
    of ``rths bench identification --held-out 10 --seed 20261128`` (true dead time 9.63 ms)
    the chosen na=2 nb=8 d=8 has d = 7.31 ms but predicts 14.4 ms (the true model: 10.7 ms).
    """
    b_star, _, d, fs = plant_polynomials(plant, fs_hz)
    _, b_minus = factor_zeros(b_star, zero_tol)
    total = float(np.sum(b_minus))
    centroid = float(np.arange(b_minus.size) @ b_minus) / total if abs(total) > 1e-300 else 0.0
    return (d + max(centroid, 0.0)) / fs


def _freq_grid(fs_hz, n_grid):
    return np.linspace(0.0, fs_hz / 2, n_grid)


def _polygon(n_sides):
    theta = 2 * np.pi * np.arange(n_sides) / n_sides
    return np.exp(-1j * theta)


def _fir_matrix(b_minus_unit, d, n_taps, freqs, fs_hz):
    w = 2 * np.pi * freqs / fs_hz
    _, bm = signal.freqz(b_minus_unit, [1.0], worN=w)
    k = np.arange(n_taps)
    return (bm * np.exp(-1j * w * d))[:, None] * np.exp(-1j * np.outer(w, k))


def _null_space_of_ones(n):
    """Particular solution and orthonormal null-space basis of ``sum(g) = 1``."""
    q, _ = np.linalg.qr(np.ones((n, 1)), mode='complete')
    return np.full(n, 1.0 / n), q[:, 1:]


def _lsi(qr, rhs, g_ineq, h_ineq):
    """``min ||a y - rhs||`` s.t. ``g_ineq y >= h_ineq`` (Lawson & Hanson LSI via LDP/NNLS).

    ``qr`` is the thin QR factorisation ``(q, r)`` of ``a`` (full column rank).
    """
    q, r = qr
    qtb = q.T @ rhs
    e = linalg.solve_triangular(r, g_ineq.T, trans='T').T       # g R^-1
    f = h_ineq - e @ qtb
    n = e.shape[1]
    mat = np.vstack([e.T, f[None, :]])
    target = np.zeros(n + 1)
    target[-1] = 1.0
    u, _ = optimize.nnls(mat, target, maxiter=50 * mat.shape[1])
    res = mat @ u - target
    if np.linalg.norm(res) < 1e-12 or abs(res[-1]) < 1e-12:
        raise ValueError('passband constraints infeasible')
    z = -res[:n] / res[-1]
    return linalg.solve_triangular(r, z + qtb)


def _linprog_free(c, a_ub, b_ub, a_eq, b_eq, method='highs'):
    """``min c x`` s.t. ``a_ub x <= b_ub``, ``a_eq x = b_eq``, x free (HiGHS).

    Returns ``(x, status)`` with status 0 = optimal, 2 = infeasible, other = failure.
    (Passing the explicit dual to HiGHS was measured 5-30x slower, so the primal is used.)
    """
    n = len(c)
    res = optimize.linprog(c, A_ub=a_ub, b_ub=b_ub, A_eq=a_eq, b_eq=b_eq,
                           bounds=[(None, None)] * n, method=method)
    if res.status == 0:
        return res.x, 0
    return None, res.status


def _infeasible_msg(plant, scheme, n_taps, fc_hz, epsilon, fs, n_grid, n_sides,
                    zero_tol=1.0):
    """Why a design with passband tolerance ``epsilon`` failed, and what to change.

    The smallest achievable passband error (an LP on the same factorisation and the same
    passband points) tells a tolerance that no filter of this length meets from one the
    solver failed on numerically (an ill-conditioned problem: too many taps for the band).
    """
    try:
        eps_min = min_passband_error(plant, n_taps, fc_hz, fs, n_grid, n_sides, zero_tol)
        eps_min /= np.cos(np.pi / n_sides)
    except ValueError:
        eps_min = float('nan')
    head = f'{scheme} n={n_taps} fc={fc_hz} Hz, epsilon={epsilon}: '
    if np.isfinite(eps_min) and eps_min < epsilon:
        return (head + f'the passband tolerance is achievable (smallest ~{eps_min:.3g}) but '
                'the constrained solver failed numerically: the problem is ill-conditioned; '
                'use fewer taps (--taps), a lower --fc, or --scheme mm')
    return (head + f'infeasible: no {n_taps}-tap filter gets the passband error below '
            f'~{eps_min:.3g}; raise --epsilon above it, add taps or lower --fc')


#: HiGHS options of the warm-started MM solves: Devex dual edge weights (measured 1.7x less
#: CPU than the default steepest edge on the bench's n = 200/300 designs).  Devex can stall
#: on these degenerate LPs (once 110000 iterations): a run that needs more than
#: ``_DEVEX_MAX_ITERATIONS`` continues from where it stopped with the default weights.
_HIGHS_OPTIONS = {'simplex_dual_edge_weight_strategy': 1}
_DEVEX_MAX_ITERATIONS = 3000


class _IncrementalLp:
    """``min c x`` s.t. ``a x <= b`` (rows added in batches), ``a_eq x = b_eq``, x free.

    Uses the HiGHS instance inside SciPy (``scipy.optimize._highspy``) when it exists, so that
    each re-solve after adding rows starts (dual simplex) from the previous optimal basis;
    otherwise every solve is a fresh ``scipy.optimize.linprog`` (same result, slower).
    """

    def __init__(self, c, a_eq, b_eq, lp_method='highs'):
        self.c = np.asarray(c, dtype=float)
        self.a_eq, self.b_eq = np.atleast_2d(a_eq), np.asarray(b_eq, dtype=float)
        self.rows, self.rhs = [], []
        self.infeasible = False
        self.lp_method = lp_method
        self.highs = None
        if lp_method == 'highs':
            try:
                # lazy: SciPy's private HiGHS module may be missing: linprog is the fall-back
                from scipy.optimize._highspy import _core
            except ImportError:          # private SciPy module: fall back to linprog
                _core = None
            if _core is not None and hasattr(_core, '_Highs'):
                self._core = _core
                self.highs = _core._Highs()
                self.highs.setOptionValue('output_flag', False)
                for key, val in _HIGHS_OPTIONS.items():
                    self.highs.setOptionValue(key, val)
                if _HIGHS_OPTIONS:
                    self.highs.setOptionValue('simplex_iteration_limit', _DEVEX_MAX_ITERATIONS)
                n = self.c.size
                inf = self.highs.getInfinity()
                self.highs.addVars(n, np.full(n, -inf), np.full(n, inf))
                for k in np.flatnonzero(self.c):
                    self.highs.changeColCost(int(k), float(self.c[k]))
                self._add(self.a_eq, self.b_eq, self.b_eq)

    def _add(self, a, lower, upper):
        a = np.ascontiguousarray(a, dtype=float)
        num, n = a.shape
        self.highs.addRows(num, np.asarray(lower, dtype=float), np.asarray(upper, dtype=float),
                           num * n, (np.arange(num) * n).astype(np.int32),
                           np.tile(np.arange(n, dtype=np.int32), num), a.ravel())

    def add_rows(self, a, b):
        """Append the rows ``a x <= b``, each scaled to unit Euclidean norm.

        Row equilibration: the minimax rows' coefficients span |B-*(f)/B-*(1)| (0.01 at a
        lightly damped zero pair to 30 near Nyquist on the bench's plant) times sqrt(n).
        (The LP on which every HiGHS variant stopped with a solve error, status 4, in the
        bench's n = 300, fc = 128 Hz design solved once its rows were scaled; the cause of
        that LP's ill-conditioning is removed in :func:`_minimax_lp`.)  A row with no
        coefficients is kept out if it holds (``0 <= b``) and makes the problem infeasible
        otherwise.
        """
        a = np.atleast_2d(np.asarray(a, dtype=float))
        b = np.asarray(b, dtype=float)
        norm = np.linalg.norm(a, axis=1)
        empty = norm <= 1e-12 * max(float(norm.max(initial=0.0)), 1.0)
        if np.any(empty & (b < 0)):
            self.infeasible = True
        a, b, norm = a[~empty], b[~empty], norm[~empty]
        a, b = a / norm[:, None], b / norm
        self.rows.append(a)
        self.rhs.append(b)
        if self.highs is not None and b.size:
            self._add(a, np.full(len(b), -self.highs.getInfinity()), b)

    def _fresh(self, tried=()):
        """Solve all rows so far afresh (cold start): HiGHS, then its dual simplex and IPM."""
        a_ub, b_ub = np.vstack(self.rows), np.concatenate(self.rhs)
        code = 4
        for method in ('highs', 'highs-ds', 'highs-ipm'):
            if method in tried:
                continue
            x, code = _linprog_free(self.c, a_ub, b_ub, self.a_eq, self.b_eq, method)
            if code in (0, 2):
                return x, code
        return None, code

    def solve(self):
        """Return ``(x, status)``: 0 optimal, 2 infeasible, other = failure."""
        if self.infeasible:
            return None, 2
        if self.highs is None:
            x, code = _linprog_free(self.c, np.vstack(self.rows), np.concatenate(self.rhs),
                                    self.a_eq, self.b_eq, self.lp_method)
            return (x, code) if code in (0, 2) else self._fresh(tried=(self.lp_method,))
        self.highs.run()
        status = self.highs.getModelStatus()
        ms = self._core.HighsModelStatus
        if status == ms.kIterationLimit:
            # stalled: resume from the current basis with the default (steepest edge) weights
            self.highs.setOptionValue('simplex_dual_edge_weight_strategy', -1)
            self.highs.setOptionValue('simplex_iteration_limit', 2 ** 31 - 1)
            self.highs.run()
            status = self.highs.getModelStatus()
        if status == ms.kOptimal:
            return np.asarray(self.highs.getSolution().col_value), 0
        if status == ms.kInfeasible:
            return None, 2
        # numerical trouble in the warm start: solve the same rows afresh
        return self._fresh()


def _minimax_lp(m, mp, bound_eps, lp_method='highs', infeasible=None, n_obj_sides=8,
                coarse=8, max_rounds=60):
    """Minimax FIR (eq. 33) as an LP solved by cutting planes; return ``(g, solver text)``.

    The full LP is ``min t`` s.t. ``Re(e^{-j theta_s}(m_i g - 1)) <= t`` for every grid
    point i and side s of a regular ``n_obj_sides``-gon (outer approximation of
    ``|m_i g - 1|``, exact to ``1/cos(pi/8)``), the passband rows
    ``Re(e^{-j theta_s}(mp_k g - 1)) <= 0.97 epsilon cos(pi/8)`` at every point k of the
    dense passband grid (inscribed 8-gon), and ``sum(g) = 1``.  Instead of handing HiGHS
    all rows at once (up to a minute for n = 300 on a loaded 2-core machine), it starts
    from the passband's every ``coarse``-th point and the objective grid's every
    ``min(coarse, 2 N / n)``-th point (at least n/2 points, i.e. n real equations for the
    n unknowns, so that the first relaxation already bounds g), all sides, plus the grid
    ends; then every row of the FULL problem is checked at the solution and, per grid
    point, its most violated side is added, until no row is violated.  A relaxation's
    optimum that satisfies every row of the full LP is the full LP's optimum, so the
    result is the same design (to the LP tolerances) as the one-shot LP; each re-solve
    warm-starts from the previous basis.  Redundant rows (0 Hz, duplicate sides at
    Nyquist: :func:`_distinct_sides`) are never added, and every row is scaled to unit norm
    (:meth:`_IncrementalLp.add_rows`).
    """
    n_taps = m.shape[1]
    rot = _polygon(n_obj_sides)
    obj_rows = np.real(rot[:, None, None] * m[None])            # S x N x n
    obj_c0 = np.real(rot)[:, None] * np.ones(m.shape[0])       # S x N
    bound = 0.97 * bound_eps * np.cos(np.pi / n_obj_sides)
    pass_rows = np.real(rot[:, None, None] * mp[None])
    pass_c0 = np.real(rot)[:, None] * np.ones(mp.shape[0])
    valid_obj = _distinct_sides(m, rot)
    valid_pass = _distinct_sides(mp, rot)
    lp = _IncrementalLp(np.r_[np.zeros(n_taps), 1.0], np.r_[np.ones(n_taps), 0.0][None, :],
                        [1.0], lp_method)
    act_obj = np.zeros(obj_c0.shape, dtype=bool)
    act_pass = np.zeros(pass_c0.shape, dtype=bool)
    new_obj, new_pass = act_obj.copy(), act_pass.copy()
    # The first relaxation holds >= n_taps / 2 objective points (>= n_taps real equations for
    # n_taps unknowns), so t > 0 and g is bounded.  With fewer (every 8th of 257 points for
    # n = 300: 33 points) the relaxation interpolates: its optimum is t = 0 on an arbitrary
    # vertex with |g| 10-1e4 times the final |g|, and from such ill-conditioned bases the
    # warm-started HiGHS and the cold linprog fallbacks failed (status 4, the bench's
    # fir-mm-n300-fc128).  The extra rows cost little: fewer cut rounds are needed.
    stride = max(1, min(coarse, 2 * m.shape[0] // n_taps))
    new_obj[:, ::stride] = new_obj[:, -1] = True
    new_pass[:, ::coarse] = new_pass[:, -1] = True
    new_obj &= valid_obj
    new_pass &= valid_pass
    n_lps = 0
    for _ in range(max_rounds):
        act_obj |= new_obj
        act_pass |= new_pass
        ro, rp = obj_rows[new_obj], pass_rows[new_pass]
        if ro.size:
            lp.add_rows(np.hstack([ro, -np.ones((ro.shape[0], 1))]), obj_c0[new_obj])
        if rp.size:
            lp.add_rows(np.hstack([rp, np.zeros((rp.shape[0], 1))]), bound + pass_c0[new_pass])
        x, status = lp.solve()
        n_lps += 1
        if status == 2:
            raise ValueError(infeasible() if infeasible else 'mm passband constraints '
                             'infeasible')
        if status != 0:
            raise ValueError(f'mm design LP failed (HiGHS status {status})')
        g, t = x[:n_taps], x[-1]
        excess_obj = np.where(valid_obj, obj_rows @ g - obj_c0 - t, -np.inf)
        excess_pass = np.where(valid_pass, pass_rows @ g - pass_c0 - bound, -np.inf)
        new_obj = _most_violated(excess_obj, 1e-7 * max(t, 1e-3)) & ~act_obj
        new_pass = _most_violated(excess_pass, 1e-6 * bound) & ~act_pass
        if not (new_obj.any() or new_pass.any()):
            break
    else:
        raise ValueError(f'mm design: cutting planes did not converge in {max_rounds} rounds')
    return g, (f'linear programme (HiGHS), polygon minimax by cutting planes: {n_lps} LPs, '
               f'{int(act_obj.sum())} of {act_obj.size} objective rows, '
               f'{int(act_pass.any(axis=0).sum())} passband points')


def _distinct_sides(m, rot):
    """Mask (sides x points) of the polygon rows of ``m`` that are not redundant.

    Where ``m_i`` is real (0 Hz and Nyquist) ``Re(e^{-j theta}(m_i g - 1)) =
    cos(theta) (m_i g - 1)``: the sides theta and -theta give the same row, the sides with
    cos(theta) = 0 an empty one, and the two extreme sides (cos = 1 and -1 for an even
    polygon) imply all others, so only those two are kept.  Where ``m_i`` is moreover a
    multiple of ``[1, ..., 1]`` (0 Hz: ``m_0 = B-*(1)/B-*(1) = 1`` per tap) every row is
    implied by the equality ``sum(g) = 1`` and none is kept.  Such duplicate and (nearly)
    dependent rows only make the LP's bases degenerate.
    """
    scale = np.max(np.abs(m), axis=1)
    real = np.max(np.abs(np.imag(m)), axis=1) <= 1e-12 * scale
    flat = real & (np.ptp(np.real(m), axis=1) <= 1e-12 * scale)
    cos = np.real(rot)
    extreme = np.zeros(rot.size, dtype=bool)
    extreme[[np.argmax(cos), np.argmin(cos)]] = True
    valid = np.ones((rot.size, m.shape[0]), dtype=bool)
    valid[:, real] = extreme[:, None]
    valid[:, flat] = False
    return valid


def _most_violated(excess, tol, local_max=True):
    """Mask (sides x points) of the most violated side at the violated points (excess > tol).

    With ``local_max`` only the points where the violation is a local maximum over
    frequency are taken (as in a Remez exchange): far fewer rows for the same optimum.
    """
    mask = np.zeros(excess.shape, dtype=bool)
    worst = excess.max(axis=0)
    keep = worst > tol
    if local_max and worst.size > 2:
        padded = np.r_[-np.inf, worst, -np.inf]
        keep &= (worst >= padded[:-2]) & (worst >= padded[2:])
    cols = np.flatnonzero(keep)
    mask[np.argmax(excess[:, cols], axis=0), cols] = True
    return mask


def _with_gain_rows(a_ls, rhs, stop, a_star, b_plus, c, n_taps, freqs, fs, weight):
    """Append ``weight |G(f)|^2`` (target 0) at the stopband points to the LS problem in g.

    ``G(f) = A*(f)/B+*(f) . H(f)`` with ``h = g / c`` is linear in g.  The seed's objective
    drives ``T_com`` to 1 over the whole band, so above the passband ``G`` tends to the
    plant's inverse, whose gain grows without bound towards Nyquist (81 dB for the Table 1
    3-pole model at 1024 Hz, n = 400, fc = 10 Hz); a small weight on the compensator's own
    gain there keeps it bounded (49 dB at 1e-6) at almost no cost in the passband.
    """
    _, ab = signal.freqz(a_star, b_plus, worN=freqs[stop], fs=fs)
    gm = (ab / c)[:, None] * np.exp(-1j * np.outer(2 * np.pi * freqs[stop] / fs,
                                                   np.arange(n_taps)))
    ws = np.sqrt(weight)
    return (np.vstack([a_ls, ws * np.real(gm), ws * np.imag(gm)]),
            np.r_[rhs, np.zeros(2 * gm.shape[0])])


def min_passband_error(plant, n_taps: int, fc_hz: float, fs_hz: float = None,
                       n_grid: int = 513, n_sides: int = 16, zero_tol: float = 1.0) -> float:
    """Smallest achievable ``max |T_com - 1|`` over the passband with unit DC gain (an LP).

    The FIR design with tolerance epsilon is feasible iff epsilon exceeds this value
    (up to the polygon factor ``1/cos(pi/S)``).
    """
    b_star, _, d, fs = plant_polynomials(plant, fs_hz)
    _, b_minus = factor_zeros(b_star, zero_tol)
    bmu = b_minus / np.sum(b_minus)
    f_pass = np.linspace(0.0, fc_hz, max(8, int(np.ceil(fc_hz / (fs / 4096))) + 1))
    m = _fir_matrix(bmu, d, n_taps, f_pass, fs)
    rot = _polygon(n_sides)
    rows = (rot[:, None, None] * m[None]).reshape(-1, n_taps)
    c0 = np.tile(np.real(rot)[:, None], (1, m.shape[0])).ravel()
    a_ub = np.hstack([np.real(rows), -np.ones((rows.shape[0], 1))])
    x, status = _linprog_free(np.r_[np.zeros(n_taps), 1.0], a_ub, c0,
                              np.r_[np.ones(n_taps), 0.0][None, :], [1.0])
    if status != 0:
        raise ValueError(f'minimum passband error LP failed (status {status})')
    return float(x[-1])


def design_fir(plant, n_taps: int = 100, fc_hz: float = 64.0, scheme: str = 'ls',
               epsilon: float = DEFAULT_EPSILON, fs_hz: float = None, n_grid: int = None,
               passband_weight: float = 1000.0, n_sides: int = 16,
               zero_tol: float = 1.0, lp_method: str = 'highs',
               gain_weight: float = 0.0) -> Design:
    """Design the FIR compensator ``G = A*/B+* . H`` (eq. 28) by LS, WLS or MM (eq. 32-36).

    ``plant`` is an :class:`ArxModel` or ``(b, a)`` in z^-1 (with ``fs_hz``).  ``n_taps`` is
    n (length of H), ``fc_hz`` the passband edge, ``epsilon`` the passband tolerance on
    ``|T_com - 1|`` (see module docstring), ``n_grid`` the number of frequency points
    from 0 to Nyquist (default 513 for LS/WLS, 257 for MM), ``zero_tol`` the modulus from
    which a zero counts as unstable (goes to B-*; below 1 it also keeps lightly damped
    zeros out of the denominator B+*), ``lp_method`` the HiGHS variant for MM ('highs':
    warm-started re-solves; 'highs-ds' or 'highs-ipm': a fresh linprog per cut round),
    ``gain_weight`` (LS/WLS) the weight of the compensator's own gain ``|G|^2`` above fc
    (:func:`_with_gain_rows`; 0: the seed's objective).
    Raises ValueError if the constraints cannot be met (the message gives the smallest
    feasible epsilon).
    """
    scheme = scheme.lower()
    if scheme not in FIR_SCHEMES:
        raise ValueError(f'FIR scheme {scheme!r} unknown; use ls, wls or mm')
    n_taps = int(n_taps)
    if n_taps < 1:
        raise ValueError(f'--taps must be >= 1, got {n_taps}')
    b_star, a_star, d, fs = plant_polynomials(plant, fs_hz)
    if not 0 < fc_hz < fs / 2:
        raise ValueError(f'--fc {fc_hz} Hz must lie in (0, {fs / 2}) Hz')
    if not epsilon > 0:
        raise ValueError(f'--epsilon must be > 0, got {epsilon}')
    if not 0 < zero_tol <= 1:
        raise ValueError(f'--zero-tol must lie in (0, 1], got {zero_tol} (1: only zeros on or '
                         'outside the unit circle count as unstable)')
    if not gain_weight >= 0:
        raise ValueError(f'gain weight must be >= 0, got {gain_weight}')
    t0 = time.perf_counter()
    b_plus, b_minus = factor_zeros(b_star, zero_tol)
    c = float(np.sum(b_minus))
    if abs(c) < 1e-300:
        raise ValueError('plant has a zero at z = 1 (B-*(1) = 0): no unit-DC-gain compensator')
    bmu = b_minus / c
    if n_grid is None:
        n_grid = 257 if scheme == 'mm' else 513
    freqs = _freq_grid(fs, n_grid)
    pb = freqs <= fc_hz
    m = _fir_matrix(bmu, d, n_taps, freqs, fs)
    rot = _polygon(n_sides)
    # 3 % design margin: the LDP/NNLS and LP solutions hold their rows to ~1e-3 relative.
    bound = 0.97 * epsilon * np.cos(np.pi / n_sides)
    # Passband constraints on a grid 4x denser than the objective grid (at most 0.25 Hz
    # at 1024 Hz), so the bound also holds between the objective's grid points.
    f_pass = np.linspace(0.0, fc_hz, max(8, int(np.ceil(fc_hz / (fs / 4096))) + 1))
    mp = _fir_matrix(bmu, d, n_taps, f_pass, fs)
    pass_rows = np.real((rot[:, None, None] * mp[None]).reshape(-1, n_taps))
    pass_c0 = np.tile(np.real(rot)[:, None], (1, mp.shape[0])).ravel()
    solver = ''
    if scheme in ('ls', 'wls'):
        w = np.ones(n_grid)
        if scheme == 'wls':
            w[pb] = passband_weight
        sw = np.sqrt(w)[:, None]
        a_ls = np.vstack([sw * np.real(m), sw * np.imag(m)])
        rhs = np.r_[np.sqrt(w), np.zeros(n_grid)]
        if gain_weight > 0:
            a_ls, rhs = _with_gain_rows(a_ls, rhs, ~pb, a_star, b_plus, c, n_taps, freqs, fs,
                                        gain_weight)
        g0, z = _null_space_of_ones(n_taps)
        az = a_ls @ z
        r0 = rhs - a_ls @ g0
        y, *_ = np.linalg.lstsq(az, r0, rcond=None)
        g = g0 + z @ y
        solver = 'equality-constrained least squares (constraints inactive)'
        if np.max(pass_rows @ g - pass_c0) > bound * (1 + 1e-9):
            # Constraint generation: the LSI is solved with the polygon rows of the passband
            # points violated so far; points are added until every passband row holds, at
            # which point the solution is the optimum of the full problem.
            n_pass = mp.shape[0]
            qr = np.linalg.qr(az)
            active = np.zeros(n_pass, dtype=bool)
            lsi_bound = bound
            for _ in range(200):
                viol = (pass_rows @ g - pass_c0 - lsi_bound).reshape(n_sides, n_pass).max(axis=0)
                new = (viol > lsi_bound * 1e-9) & ~active
                err_max = np.max(np.abs(mp @ g - 1.0))
                if not new.any():
                    if err_max <= epsilon or not active.any():
                        break
                    # NNLS round-off on a large active set: tighten the bound and re-solve.
                    lsi_bound *= 0.98 * epsilon / err_max
                active |= new
                sel = np.tile(active, n_sides)
                g_in = -(pass_rows[sel] @ z)
                h_in = -(lsi_bound + pass_c0[sel] - pass_rows[sel] @ g0)
                try:
                    y = _lsi(qr, r0, g_in, h_in)
                except ValueError:
                    raise ValueError(_infeasible_msg(plant, scheme, n_taps, fc_hz, epsilon,
                                                     fs, n_grid, n_sides, zero_tol)) from None
                g = g0 + z @ y
            solver = ('inequality-constrained least squares (LSI -> LDP -> NNLS, '
                      f'{int(active.sum())} active passband points)')
    else:
        g, solver = _minimax_lp(m, mp, bound_eps=epsilon, lp_method=lp_method,
                                infeasible=lambda: _infeasible_msg(
                                    plant, scheme, n_taps, fc_hz, epsilon, fs, n_grid,
                                    n_sides, zero_tol))
    h = g / c
    taps = np.convolve(a_star, h)
    design_s = time.perf_counter() - t0
    tcom = m @ g
    tpass = mp @ g
    info = {
        'n_taps': n_taps, 'fc_hz': float(fc_hz), 'epsilon': float(epsilon),
        'zero_tol': float(zero_tol), 'solver': solver, 'design_s': design_s,
        'gain_weight': float(gain_weight),
        'passband_max_error': float(np.max(np.abs(tpass - 1.0))),
        'max_error_all': float(np.max(np.abs(tcom - 1.0))),
        'dc_gain_error': float(abs(np.sum(g) - 1.0)),
        'n_unstable_zeros': int(b_minus.size - 1),
        'dead_time': int(d),
    }
    if info['passband_max_error'] > epsilon * (1 + 1e-6) or info['dc_gain_error'] > 1e-8:
        raise ValueError(_infeasible_msg(plant, scheme, n_taps, fc_hz, epsilon, fs, n_grid,
                                         n_sides, zero_tol)
                         + f' (the solution reached {info["passband_max_error"]:.3g})')
    return Design(scheme, taps, np.asarray(b_plus, dtype=float), fs, info).check()


def design_inverse(fs_hz: float, delay_ms: float) -> Design:
    """Inverse compensation (eq. 1-2): ``G = a - (a - 1) z^-1`` with ``a = tau + 1``."""
    tau = float(delay_ms) * 1e-3 * float(fs_hz)
    a_t = tau + 1.0
    return Design('inverse', np.array([a_t, -(a_t - 1.0)]), np.array([1.0]), float(fs_hz),
                  {'delay_ms': float(delay_ms), 'a_tilde': a_t}).check()


def design_mff(poles, alpha: float, fs_hz: float, method: str = 'bilinear') -> Design:
    """Model-based feed-forward (eq. 4) from continuous-time ``poles`` [rad/s] or a Table 1 name.

    ``G(s) = alpha^k prod(s - p_i)/prod(s - alpha p_i)`` (unit DC gain), discretised at
    ``fs_hz`` with ``scipy.signal.cont2discrete`` (``method``, default Tustin).
    """
    if isinstance(poles, str):
        kind = poles
        poles = actuator_poles(poles)
    else:
        kind = 'custom'
        poles = np.asarray(poles, dtype=complex)
    k = poles.size
    num = np.real(alpha ** k * np.poly(poles))
    den = np.real(np.poly(alpha * poles))
    if method == 'bilinear':
        bz, az = signal.bilinear(num, den, fs=fs_hz)
    else:
        bz, az, _ = signal.cont2discrete((num, den), 1.0 / fs_hz, method=method)
    bz = np.asarray(bz, dtype=float).ravel()
    az = np.asarray(az, dtype=float).ravel()
    return Design('mff', bz / az[0], az / az[0], float(fs_hz),
                  {'alpha': float(alpha), 'model': kind, 'discretisation': method}).check()


def _factored(plant, fs_hz, zero_tol=1.0):
    b_star, a_star, d, fs = plant_polynomials(plant, fs_hz)
    b_plus, b_minus = factor_zeros(b_star, zero_tol)
    return a_star, b_plus, b_minus, d, fs


def design_npz(plant, fs_hz: float = None) -> Design:
    """NPZ-Ignore (eq. 8): ``A*/(B+* B-*(1))``."""
    a_star, b_plus, b_minus, d, fs = _factored(plant, fs_hz)
    return Design('npz', a_star.copy(), b_plus * np.sum(b_minus), fs, {'dead_time': d}).check()


def design_zpetc(plant, fs_hz: float = None) -> Design:
    """Design the modified causal ZPETC (eq. 12): ``A* B-(z^-1)/(B+* B-*(1)^2)``, q samples late."""
    a_star, b_plus, b_minus, d, fs = _factored(plant, fs_hz)
    taps = np.convolve(a_star, b_minus[::-1]) / np.sum(b_minus) ** 2
    return Design('zpetc', taps, b_plus.copy(), fs,
                  {'q': int(b_minus.size - 1), 'dead_time': d}).check()


def design_zmetc(plant, fs_hz: float = None) -> Design:
    """ZMETC (eq. 14): ``A*/(B+* B-(z^-1))``."""
    a_star, b_plus, b_minus, d, fs = _factored(plant, fs_hz)
    return Design('zmetc', a_star.copy(), np.convolve(b_plus, b_minus[::-1]), fs,
                  {'dead_time': d}).check()


def design_ls(plant, fs_hz: float = None, **options) -> Design:
    """Design the FIR scheme ``ls`` (:func:`design_fir`)."""
    return design_fir(plant, scheme='ls', fs_hz=fs_hz, **options)


def design_wls(plant, fs_hz: float = None, **options) -> Design:
    """Design the FIR scheme ``wls`` (:func:`design_fir`)."""
    return design_fir(plant, scheme='wls', fs_hz=fs_hz, **options)


def design_mm(plant, fs_hz: float = None, **options) -> Design:
    """Design the FIR scheme ``mm`` (:func:`design_fir`)."""
    return design_fir(plant, scheme='mm', fs_hz=fs_hz, **options)


def design_inverse_for(plant, fs_hz: float = None, delay_ms: float = None,
                       band_hz: float = 20.0) -> Design:
    """Inverse compensation of ``plant``: ``delay_ms``, else the plant's delay over ``band_hz``."""
    b_star, a_star, d, fs = plant_polynomials(plant, fs_hz)
    if delay_ms is None:
        delay_ms = time_delay_ms(np.r_[np.zeros(d), b_star], a_star, fs, float(band_hz))
    return design_inverse(fs, delay_ms)


def design_mff_for(plant, fs_hz: float = None, alpha: float = 7.0,
                   poles: str = '3pole') -> Design:
    """Model-based feed-forward at the plant's rate from the Table 1 ``poles`` model."""
    return design_mff(poles, float(alpha), plant_polynomials(plant, fs_hz)[3])


def design(plant, scheme: str, fs_hz: float = None, **options) -> Design:
    """Design the compensator ``scheme`` (a designed name of :data:`.schemes.SCHEMES`).

    Options: FIR -> ``n_taps, fc_hz, epsilon, ...`` (:func:`design_fir`); inverse ->
    ``delay_ms`` (default: the plant's delay over ``band_hz``, default 20 Hz); mff ->
    ``alpha`` (default 7), ``poles`` (default '3pole').  A non-FIR scheme takes only the
    options its entry names; the others are ignored.
    """
    entry = SCHEMES.entry(str(scheme).lower())
    if not entry.designer:
        raise ValueError(f'scheme {scheme!r} is not designed; use one of {", ".join(designed())}')
    if not entry.fir:
        options = {k: v for k, v in options.items() if k in entry.options}
    return entry.design_function()(plant, fs_hz=fs_hz, **options)


def compensated(plant, comp: Design, fs_hz: float = None):
    """``(num, den)`` of the compensated system ``T . G`` in z^-1."""
    b_star, a_star, d, _ = plant_polynomials(plant, fs_hz or comp.fs_hz)
    return (np.convolve(np.r_[np.zeros(d), b_star], comp.taps),
            np.convolve(a_star, comp.denominator))


def predict(plant, comp: Design, band_hz: float, fs_hz: float = None,
            n_points: int = 512) -> dict:
    """Predicted indicators of ``T . G`` from the plant model over ``0 < f <= band_hz``.

    Returns delay_ms (eq. 42 averaged), gain_error_db (max | 20 log10 |T_com| |) and
    highpass_gain_db (max 20 log10 |T_com| above the band, up to Nyquist).
    """
    num, den = compensated(plant, comp, fs_hz)
    fs = comp.fs_hz
    delay = time_delay_ms(num, den, fs, band_hz, n_points)
    f_in = np.linspace(band_hz / n_points, band_hz, n_points)
    f_out = np.linspace(band_hz, fs / 2, 2 * n_points)
    _, h_in = signal.freqz(num, den, worN=f_in, fs=fs)
    _, h_out = signal.freqz(num, den, worN=f_out, fs=fs)
    return {'delay_ms': float(delay),
            'gain_error_db': float(np.max(np.abs(20 * np.log10(np.abs(h_in))))),
            'highpass_gain_db': float(np.max(20 * np.log10(np.abs(h_out))))}


#: Weights of the --auto score (all in "ms-equivalents"; lower is better).
AUTO_WEIGHTS = {'delay_ms': 1.0, 'gain_error_db': 1.0, 'highpass_db_over_6': 0.1,
                'per_coefficient': 1e-4}


def auto_score(pred: dict, n_coefficients: int) -> float:
    """Score of a candidate from its predicted indicators (see :data:`AUTO_WEIGHTS`).

    ``|delay| [ms] + gain error [dB] + 0.1 * max(0, high-pass gain above the band - 6 dB)
    + 1e-4 * (number of numerator + denominator coefficients)`` -- i.e. 1 dB of gain
    error weighs as much as 1 ms of delay, each dB of high-pass gain beyond 6 dB (noise
    amplification) as 0.1 ms, and 1000 coefficients (about 4 us per step) as 0.1 ms.
    """
    w = AUTO_WEIGHTS
    return (w['delay_ms'] * abs(pred['delay_ms']) + w['gain_error_db'] * pred['gain_error_db']
            + w['highpass_db_over_6'] * max(0.0, pred['highpass_gain_db'] - 6.0)
            + w['per_coefficient'] * n_coefficients)


def auto_design(plant, bandwidth_hz: float, fs_hz: float = None, epsilon: float = None,
                taps=(25, 50, 100, 200), fc_factors=(1.5, 2.0, 3.0, 4.0),
                schemes=None, log=None,
                zero_tol: float = 1.0, progress=None):
    """Search scheme, n and fc for the operating ``bandwidth_hz``; return (best, table).

    Every candidate is designed on the plant model and scored by :func:`auto_score` from
    its predicted indicators over ``0 < f <= bandwidth_hz``; ``zero_tol`` is passed to
    the FIR candidates (:func:`design_fir`); ``schemes`` default to the registry's
    ``auto`` entries.  ``log(text)`` gets a line per candidate,
    ``progress(done, total)`` the count.  ``table`` lists dicts
    (scheme, n_taps, fc_hz, score, delay_ms, gain_error_db, highpass_gain_db,
    n_coefficients, error) sorted best first.
    """
    _, _, _, fs = plant_polynomials(plant, fs_hz)
    schemes = auto_schemes() if schemes is None else schemes
    if not 0 < bandwidth_hz < fs / 2:
        raise ValueError(f'--bandwidth {bandwidth_hz} Hz must lie in (0, {fs / 2}) Hz')
    eps = DEFAULT_EPSILON if epsilon is None else epsilon
    candidates = []
    for scheme in schemes:
        if scheme in FIR_SCHEMES:
            for n in taps:
                for k in fc_factors:
                    fc = min(k * bandwidth_hz, 0.45 * fs)
                    candidates.append((scheme, n, fc))
        else:
            candidates.append((scheme, None, None))
    table, best = [], None
    candidates = list(dict.fromkeys(candidates))
    for scheme, n, fc in candidates:
        row = {'scheme': scheme, 'n_taps': n, 'fc_hz': fc}
        try:
            if scheme in FIR_SCHEMES:
                comp = design_fir(plant, n, fc, scheme, eps, fs_hz=fs_hz, zero_tol=zero_tol)
            else:
                comp = design(plant, scheme, fs_hz=fs_hz, band_hz=bandwidth_hz)
            pred = predict(plant, comp, bandwidth_hz, fs_hz)
            ncoef = comp.taps.size + comp.denominator.size - 1
            row.update(pred, n_coefficients=int(ncoef), score=auto_score(pred, ncoef),
                       error='')
            if best is None or row['score'] < best[1]['score']:
                best = (comp, row)
        except ValueError as exc:
            row.update(score=float('inf'), error=str(exc))
        table.append(row)
        if progress is not None:
            progress(len(table), len(candidates))
        if log is not None:
            log(f"  {scheme:6s} n={n!s:>4} fc={fc!s:>6}: "
                + (f"score {row['score']:.3f}" if not row['error'] else 'infeasible'))
    table.sort(key=lambda r: r['score'])
    if best is None:
        raise ValueError('no candidate design was feasible; raise --epsilon')
    best[0].info.update(auto_score=best[1]['score'], bandwidth_hz=float(bandwidth_hz))
    return best[0], table


def target_lowpass(order: int, cutoff_hz: float, fs_hz: float):
    """All-pole unit-DC-gain low-pass ``g / aL(z^-1)``: Butterworth poles mapped by e^{sT}."""
    _, poles, _ = signal.butter(order, 2 * np.pi * cutoff_hz, analog=True, output='zpk')
    a_l = np.real(np.poly(np.exp(poles / fs_hz)))
    return float(np.sum(a_l)), a_l
