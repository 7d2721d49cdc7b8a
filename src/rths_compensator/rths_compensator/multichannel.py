"""Simultaneous multi-channel identification of an N x N actuator plant.

Several actuators on one specimen are coupled through it: the command of actuator j moves
actuator i too.  Identifying one actuator at a time (the others held at zero) takes N
tests; this module identifies the whole N x N plant from one test in which every actuator
is excited at once with its own uncorrelated signal (:func:`excitation`):

* ``blwn``: an independent band-limited white noise per channel (uncorrelated in
  expectation);
* ``multisine``: a random-phase multisine per channel on the record's frequency grid, the
  lines of the band dealt out in turn to the channels (line k to channel k mod N), so the
  channels are orthogonal over the record exactly.

The model is a discrete state-space ``x(k+1) = A x(k) + B u(k)``, ``y(k) = C x(k) + D u(k)``
of order n (:class:`MimoModel`), fitted by a subspace method (PO-MOESP, Verhaegen 1994: the
column space of the extended observability matrix from an LQ factorisation of the block
Hankel matrices of the future outputs against the future inputs, with the past inputs and
outputs as instruments; ``A`` and ``C`` from its shift invariance) followed by ``B``, ``D``
and each record's initial state by linear least squares on the SIMULATION error.  Both
steps are consistent with white sensor noise on the outputs; a multi-input ARX with one
shared denominator is not (its equation error weighs the noise by the denominator, which
biased the static gains of the maRTHS plant's 2 x 2 identification by up to 50 %), and
unlike a shared-denominator form every input keeps its own dynamics.

Order selection (:func:`identify_multichannel`): each order up to ``n_max`` is fitted on the
training records and scored on the held-out validation records by the simulated output's
error, BIC ``ln(MSE) + ln(N) dim / N`` with ``dim = n (m + p + r) + m p`` (r validation
records, each with its fitted initial state; ``m p`` only with a feedthrough ``D``; the same
criterion as the single-actuator ARX grid, seed eq. 40); unstable models are skipped.

The cross-coupling (:func:`cross_coupling`) is reported per pair (i, j) (output i, input j)
as the DC gain and the peak gain over the band, each also relative to the diagonal
element of the same output (i, i).

Plain numpy/scipy, no rclpy.  Units are the caller's (the maRTHS benchmark uses mm).
"""

import dataclasses
import math
import os

import numpy as np
from scipy import linalg
from scipy.signal import butter, csd, lfilter
import yaml

from rths_common.files import atomic_open
from rths_numerical.signals import blwn

from .design import target_lowpass
from .estimation import excited_band_hz, split_point
from .identification import _plain

EXCITATIONS = ('blwn', 'multisine')


def excitation(kind: str, n_channels: int, duration_s: float, fs_hz: float, band_hz,
               peak: float, rng=None, taper_s: float = 0.5) -> np.ndarray:
    """Return uncorrelated excitation signals, shape ``(samples, n_channels)``.

    ``kind`` is ``blwn`` or ``multisine`` (module docstring); ``band_hz`` is ``f_max`` or
    ``(f_min, f_max)``; ``peak`` the largest absolute value per channel; ``taper_s`` fades
    each signal in and out (a multisine is then orthogonal up to the taper's edges).
    """
    if kind not in EXCITATIONS:
        raise ValueError(f'excitation kind {kind!r}: use one of {", ".join(EXCITATIONS)}')
    if int(n_channels) < 1:
        raise ValueError(f'n_channels must be >= 1, got {n_channels}')
    rng = np.random.default_rng(rng)
    n_ch = int(n_channels)
    if kind == 'blwn':
        return np.stack([blwn(duration_s, fs_hz, band_hz, peak, rng, taper_s)
                         for _ in range(n_ch)], axis=1)
    n = int(round(duration_s * fs_hz))
    f_lo, f_hi = (0.0, float(band_hz)) if np.isscalar(band_hz) else map(float, band_hz)
    if not 0.0 <= f_lo < f_hi <= fs_hz / 2:
        raise ValueError(f'multisine band ({f_lo}, {f_hi}) Hz must satisfy '
                         f'0 <= f_min < f_max <= fs/2 = {fs_hz / 2}')
    freqs = np.fft.rfftfreq(n, d=1.0 / fs_hz)
    lines = np.flatnonzero((freqs >= f_lo) & (freqs <= f_hi) & (freqs > 0))
    if lines.size < n_ch:
        raise ValueError(f'multisine band ({f_lo}, {f_hi}) Hz holds {lines.size} lines of '
                         f'{fs_hz / n:g} Hz for {n_ch} channels; record longer or widen it')
    out = np.empty((n, n_ch))
    m = min(int(round(taper_s * fs_hz)), n // 2)
    ramp = 0.5 * (1 - np.cos(np.linspace(0.0, np.pi, m)))
    for j in range(n_ch):
        spectrum = np.zeros(freqs.size, complex)
        own = lines[j::n_ch]
        spectrum[own] = np.exp(2j * np.pi * rng.random(own.size))
        x = np.fft.irfft(spectrum, n)
        if m:
            x[:m] *= ramp
            x[n - m:] *= ramp[::-1]
        out[:, j] = x * (peak / np.max(np.abs(x)))
    return out


@dataclasses.dataclass
class MimoModel:
    """Discrete state-space model of an N x N plant at ``fs_hz`` (inputs m, outputs p)."""

    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    fs_hz: float
    selection: dict = dataclasses.field(default_factory=dict)

    @property
    def order(self) -> int:
        """Return the state dimension n."""
        return self.a.shape[0]

    def dc_gain(self) -> np.ndarray:
        """Return the static gains ``C (I - A)^-1 B + D`` (p x m)."""
        return self.c @ np.linalg.solve(np.eye(self.order) - self.a, self.b) + self.d

    def freq_resp(self, f_hz) -> np.ndarray:
        """Frequency response at ``f_hz`` [Hz], shape ``(len(f), p, m)``."""
        z = np.exp(2j * np.pi * np.atleast_1d(np.asarray(f_hz, float)) / self.fs_hz)
        eye = np.eye(self.order)
        return np.stack([self.c @ np.linalg.solve(zk * eye - self.a, self.b) + self.d
                         for zk in z])

    def is_stable(self) -> bool:
        """Return True if every pole lies strictly inside the unit circle."""
        return bool(np.max(np.abs(np.linalg.eigvals(self.a)), initial=0.0) < 1.0)

    def simulate(self, u, x0=None) -> np.ndarray:
        """Noise-free outputs (samples x p) for inputs ``u`` (samples x m) from ``x0``."""
        u = _as_2d(u)
        x = _states(self.a, u @ self.b.T, x0)
        return x @ self.c.T + u @ self.d.T

    def to_dict(self) -> dict:
        """Plain-Python dict (for JSON/YAML)."""
        return {'kind': 'state_space', 'fs_hz': self.fs_hz, 'order': self.order,
                'a': self.a.tolist(), 'b': self.b.tolist(), 'c': self.c.tolist(),
                'd': self.d.tolist()}


def _as_2d(x) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    return x[:, None] if x.ndim == 1 else x


def _modes(a):
    """``(lam, V, V^-1)`` of ``a``, or None when the eigenvectors are ill-conditioned."""
    lam, v = np.linalg.eig(a)
    if np.linalg.cond(v) > 1e8:
        return None
    return lam, v, np.linalg.inv(v)


def _mode_filter(lam, w):
    """``xi_l(k+1) = lam_l xi_l(k) + w_l(k)`` from rest for every mode l (w: samples x n)."""
    out = np.empty(w.shape, complex)
    for col, lam_l in enumerate(lam):
        out[:, col] = lfilter([0.0, 1.0], [1.0, -lam_l], w[:, col])
    return out


def _states(a, w, x0=None) -> np.ndarray:
    """States ``x(k)`` (samples x n) of ``x(k+1) = A x(k) + w(k)`` from ``x0``."""
    n = a.shape[0]
    modes = _modes(a)
    if modes is None:   # a defective A: the plain recursion
        x = np.zeros((w.shape[0], n))
        xk = np.zeros(n) if x0 is None else np.asarray(x0, float)
        for k in range(w.shape[0]):
            x[k] = xk
            xk = a @ xk + w[k]
        return x
    lam, v, vi = modes
    xi = _mode_filter(lam, w @ vi.T)
    if x0 is not None:
        xi += (lam[None, :] ** np.arange(w.shape[0])[:, None]) * (vi @ x0)[None, :]
    return np.real(xi @ v.T)


def _hankel(x, rows: int, cols: int) -> np.ndarray:
    """Block Hankel matrix ``rows`` blocks deep (each block x.shape[1] rows), ``cols`` wide."""
    return np.vstack([x[i:i + cols].T for i in range(rows)])


def observability_space(records, horizon: int):
    """PO-MOESP: ``(U, s)`` of the SVD spanning the extended observability matrix.

    ``records``: ``(u, y)`` pairs (samples x m, samples x p); ``horizon``: past = future
    block rows.  The records' Hankel columns are joined before one LQ factorisation
    (computed as the Cholesky factor of the Gram matrix, far cheaper than a QR of the
    tall data matrix).
    """
    blocks = []
    for u, y in records:
        u, y = _as_2d(u), _as_2d(y)
        cols = u.shape[0] - 2 * horizon + 1
        if cols < 1:
            raise ValueError(f'record of {u.shape[0]} samples is shorter than 2 x horizon '
                             f'({2 * horizon})')
        uf = _hankel(u[horizon:], horizon, cols)
        up = _hankel(u, horizon, cols)
        yp = _hankel(y, horizon, cols)
        yf = _hankel(y[horizon:], horizon, cols)
        blocks.append(np.vstack([uf, up, yp, yf]))
    h = np.hstack(blocks)
    m, p = _as_2d(records[0][0]).shape[1], _as_2d(records[0][1]).shape[1]
    # LQ through the Gram matrix: L L^T = H H^T / N (a Cholesky factor is the L of the LQ)
    gram = h @ h.T / h.shape[1]
    ridge = 1e-12 * np.trace(gram) / gram.shape[0]
    ell = linalg.cholesky(gram + ridge * np.eye(gram.shape[0]), lower=True,
                          check_finite=False)
    i_u = horizon * m
    i_w = i_u + horizon * (m + p)
    l32 = ell[i_w:, i_u:i_w]
    u_svd, s, _ = np.linalg.svd(l32, full_matrices=False)
    return u_svd, s


def _ac_from_space(u_svd, s, order: int, p: int):
    gamma = u_svd[:, :order] * np.sqrt(s[:order])
    c = gamma[:p]
    a = np.linalg.lstsq(gamma[:-p], gamma[p:], rcond=None)[0]
    return a, c


def _free_response(a, c, n_s: int, modes=None) -> np.ndarray:
    """Columns (samples*p x n): the outputs ``C A^k e_r`` of each unit initial state."""
    n = a.shape[0]
    if modes is None:
        modes = _modes(a)
    if modes is None:
        return np.stack([(_states(a, np.zeros((n_s, n)), e) @ c.T).ravel()
                         for e in np.eye(n)], axis=1)
    lam, v, vi = modes
    powers = lam[None, :] ** np.arange(n_s)[:, None]
    cv = c @ v
    # y_i(k) for x0 = e_r: sum_l cv[i, l] lam_l^k vi[l, r]
    out = np.real(np.einsum('kl,il,lr->kir', powers, cv, vi))
    return out.reshape(n_s * c.shape[0], n)


def _regressors(a, c, u, feedthrough: bool, lam_v=None):
    """Columns of y (samples*p) linear in vec(B), vec(D) and x0, for one record."""
    n, p = a.shape[0], c.shape[0]
    u = _as_2d(u)
    n_s, m = u.shape
    cols = []
    modes = lam_v if lam_v is not None else _modes(a)
    for j in range(m):
        if modes is not None:
            lam, v, vi = modes
            z = _mode_filter(lam, np.repeat(u[:, j:j + 1], n, axis=1))
        for r in range(n):
            if modes is None:
                e = np.zeros((n_s, n))
                e[:, r] = u[:, j]
                x = _states(a, e)
            else:
                x = np.real((z * vi[:, r][None, :]) @ v.T)
            cols.append((x @ c.T).ravel())
    if feedthrough:
        for j in range(m):
            for i in range(p):
                y = np.zeros((n_s, p))
                y[:, i] = u[:, j]
                cols.append(y.ravel())
    x0_cols = _free_response(a, c, n_s, modes)
    return np.stack(cols, axis=1), x0_cols


def _lsq(phi, y) -> np.ndarray:
    """Least squares ``phi theta ~ y`` through the column-scaled normal equations.

    ``phi`` is tall (samples x a few dozen columns): its Gram matrix is small, and the
    column scaling keeps it well conditioned enough for these fits.
    """
    scale = np.linalg.norm(phi, axis=0)
    scale[scale == 0] = 1.0
    ps = phi / scale
    return np.linalg.lstsq(ps.T @ ps, ps.T @ y, rcond=None)[0] / scale


def fit_bd(a, c, records, feedthrough: bool = False):
    """``(B, D)`` minimising the simulation error over ``records`` (one x0 per record)."""
    n, p = a.shape[0], c.shape[0]
    m = _as_2d(records[0][0]).shape[1]
    modes = _modes(a)
    phis, x0s, ys = [], [], []
    for u, y in records:
        phi, phx = _regressors(a, c, u, feedthrough, modes)
        phis.append(phi)
        x0s.append(phx)
        ys.append(_as_2d(y).ravel())
    k = phis[0].shape[1]
    rows = sum(ph.shape[0] for ph in phis)
    big = np.zeros((rows, k + n * len(records)))
    at = 0
    for idx, (phi, phx) in enumerate(zip(phis, x0s, strict=True)):
        big[at:at + phi.shape[0], :k] = phi
        big[at:at + phi.shape[0], k + n * idx:k + n * (idx + 1)] = phx
        at += phi.shape[0]
    theta = _lsq(big, np.concatenate(ys))
    b = theta[:n * m].reshape(m, n).T
    d = theta[n * m:k].reshape(m, p).T if feedthrough else np.zeros((p, m))
    return b, d


def validation_error(model: MimoModel, records) -> tuple:
    """``(mse, n_samples)`` of the simulated outputs over ``records`` (x0 fitted per record).

    The initial state is the least-squares one of each record (the record need not start
    at rest); the MSE is over every output and sample.
    """
    sse, count = 0.0, 0
    for u, y in records:
        u, y = _as_2d(u), _as_2d(y)
        resid = y - model.simulate(u)
        phx = _free_response(model.a, model.c, u.shape[0])
        x0 = _lsq(phx, resid.ravel())
        resid = resid.ravel() - phx @ x0
        sse += float(resid @ resid)
        count += resid.size
    return sse / count, count


def identify_multichannel(records_train, records_val, fs_hz: float, n_max: int = 12,
                          horizon: int = 30, feedthrough: bool = False,
                          orders=None, progress=None) -> MimoModel:
    """Identify the N x N plant from simultaneous excitation; select the order.

    ``records_*``: ``(u, y)`` pairs, inputs (samples x m) and outputs (samples x p) of the
    same test (every actuator excited at once).  Orders ``1..n_max`` (or ``orders``) are
    fitted on the training records and scored on the validation records by BIC of the
    simulation error; the selected model carries ``selection`` (per order: MSE, FIT as
    sqrt(MSE)/std(y), BIC, stable) and the subspace's singular values.
    """
    if not records_train or not records_val:
        raise ValueError('identify_multichannel needs training and validation records')
    m = _as_2d(records_train[0][0]).shape[1]
    p = _as_2d(records_train[0][1]).shape[1]
    for u, y in list(records_train) + list(records_val):
        if _as_2d(u).shape[1] != m or _as_2d(y).shape[1] != p or len(u) != len(y):
            raise ValueError('every record must hold the same channels, inputs and outputs '
                             'of equal length')
    horizon = int(horizon)
    orders = list(orders) if orders is not None else list(range(1, int(n_max) + 1))
    if max(orders) > horizon * p:
        raise ValueError(f'order {max(orders)} exceeds horizon x outputs '
                         f'({horizon} x {p}); raise horizon')
    u_svd, s = observability_space(records_train, horizon)
    y_std = float(np.std(np.concatenate([_as_2d(y) for _, y in records_val])))
    rows, best = [], None
    for step, order in enumerate(orders):
        a, c = _ac_from_space(u_svd, s, order, p)
        stable = bool(np.max(np.abs(np.linalg.eigvals(a))) < 1.0)
        row = {'order': order, 'stable': stable}
        if stable:
            b, d = fit_bd(a, c, records_train, feedthrough)
            model = MimoModel(a, b, c, d, float(fs_hz))
            mse, count = validation_error(model, records_val)
            dim = order * (m + p + len(records_val)) + (m * p if feedthrough else 0)
            row.update(mse=mse, fit=math.sqrt(mse) / y_std if y_std > 0 else float('nan'),
                       bic=math.log(mse) + math.log(count) * dim / count)
            if best is None or row['bic'] < best[0]['bic']:
                best = (row, model)
        rows.append(row)
        if progress is not None:
            progress(step + 1, len(orders))
    if best is None:
        raise ValueError('no stable model at any order; record longer, excite more, or '
                         'change the horizon')
    model = best[1]
    model.selection = {'criterion': 'bic (simulation error on the validation records)',
                       'order': model.order, 'horizon': horizon,
                       'feedthrough': bool(feedthrough),
                       'singular_values': [float(v) for v in s[:max(orders) + 4]],
                       'grid': rows}
    return model


def cross_coupling(model: MimoModel, band_hz: float, n_freq: int = 400) -> dict:
    """Per pair (output i, input j): DC gain and peak gain over ``0..band_hz``.

    ``dc_rel`` and ``peak_rel`` divide each pair by the diagonal element of the same output
    (|G_ij| / |G_ii|), the coupling actuator j adds to actuator i's own response.
    """
    dc = model.dc_gain()
    f = np.linspace(0.0, float(band_hz), int(n_freq))
    peak = np.max(np.abs(model.freq_resp(f)), axis=0)
    diag_dc = np.abs(np.diag(dc))[:, None]
    diag_pk = np.diag(peak)[:, None]
    return {'band_hz': float(band_hz),
            'dc_gain': dc.round(5).tolist(),
            'peak_gain': peak.round(5).tolist(),
            'dc_rel': (np.abs(dc) / diag_dc).round(5).tolist(),
            'peak_rel': (peak / diag_pk).round(5).tolist()}


# ----------------------------------------------------------------------------- the design
def design_coupled_fir(freq_resp, fs_hz: float, n_taps: int, fc_hz: float, lowpass_hz: float,
                       stop_weight: float = 0.1, gain_weight: float = 1e-3) -> np.ndarray:
    """Least-squares N x N FIR ``G`` with ``P G`` close to ``L I`` (L an order-4 low-pass).

    ``freq_resp(f)`` gives the plant's N x N response at frequencies ``f`` [Hz] (shape
    f x N x N, e.g. :meth:`MimoModel.freq_resp`).  The error ``P G - L I`` weighs 1 up to
    ``fc_hz`` and ``stop_weight`` above; ``|G|`` above ``fc_hz`` weighs ``gain_weight`` (it
    bounds the high-frequency gain, which the RTHS loop feeds back through the specimen's
    inertia); ``L`` is :func:`rths_compensator.design.target_lowpass` at ``lowpass_hz``.
    Returns the taps (N x N x ``n_taps``): ``taps[i, l]`` maps target l to command i, the
    layout of :class:`rths_compensator.filters.CoupledFir` (``coupled_taps``).  One least-
    squares problem per target l (its column of ``G``).
    """
    f = np.linspace(0.0, fs_hz / 2, 513)
    z1 = np.exp(-2j * np.pi * f / fs_hz)
    p = freq_resp(f)
    n = p.shape[1]
    gain, a_l = target_lowpass(4, lowpass_hz, fs_hz)
    ell = gain / np.polyval(a_l[::-1], z1)
    e = z1[:, None] ** np.arange(n_taps)[None, :]
    w = np.where(f <= fc_hz, 1.0, stop_weight)
    reg = np.where(f > fc_hz, gain_weight, 0.0)[:, None] * e
    zero = np.zeros_like(e)
    taps = np.zeros((n, n, n_taps))
    for j in range(n):
        # unknowns: the taps of G[c, j] for every command c, one block each
        rows = [w[:, None] * np.hstack([p[:, i, c, None] * e for c in range(n)])
                for i in range(n)]
        rhs = [w * (ell if i == j else 0.0 * ell) for i in range(n)]
        rows += [np.hstack([reg if c == k else zero for c in range(n)]) for k in range(n)]
        rhs += [np.zeros(f.size)] * n
        a = np.vstack(rows)
        b = np.concatenate(rhs)
        sol = np.linalg.lstsq(np.vstack([a.real, a.imag]), np.concatenate([b.real, b.imag]),
                              rcond=None)[0]
        for c in range(n):
            taps[c, j] = sol[c * n_taps:(c + 1) * n_taps]
    return taps


def coupled_response(model_resp, taps, f_hz, fs_hz: float) -> np.ndarray:
    """Return ``P(f) G(f)`` (f x N x N): the compensated loop of plant response ``model_resp``."""
    z1 = np.exp(-2j * np.pi * np.asarray(f_hz, float) / fs_hz)
    g = np.einsum('ilk,fk->fil', np.asarray(taps, float),
                  z1[:, None] ** np.arange(np.shape(taps)[2])[None, :])
    return np.einsum('fij,fjl->fil', model_resp, g)


def coupled_prediction(model: MimoModel, taps, lowpass_hz: float, band_hz: float) -> dict:
    """Predicted figures of the coupled FIR ``taps`` on the plant ``model`` over the band.

    ``tracking_error_pct``: the largest ``|(P G)_ii - L|`` as % of ``|L|`` (L the design's
    target low-pass); ``residual_coupling_pct``: the largest ``|(P G)_ij| / |(P G)_ii|``
    (i != j) in %; ``plant_coupling_pct`` the same of the plant alone; ``gain_peak`` and
    ``gain_peak_hz``: the compensator's largest element gain up to fs/2 and where.
    """
    fs = model.fs_hz
    f = np.linspace(0.0, float(band_hz), 200)
    p = model.freq_resp(f)
    loop = coupled_response(p, taps, f, fs)
    gain, a_l = target_lowpass(4, lowpass_hz, fs)
    ell = gain / np.polyval(a_l[::-1], np.exp(-2j * np.pi * f / fs))
    n = p.shape[1]
    diag = np.stack([loop[:, i, i] for i in range(n)], axis=1)
    off = ~np.eye(n, dtype=bool)

    def coupling(m):
        d = np.abs(np.stack([m[:, i, i] for i in range(n)], axis=1))[:, :, None]
        return float(100.0 * np.max(np.abs(m)[:, off] / np.broadcast_to(d, m.shape)[:, off]))

    f_all = np.linspace(0.0, fs / 2, 513)
    g = np.abs(coupled_response(np.broadcast_to(np.eye(n), (f_all.size, n, n)), taps, f_all,
                                fs))
    k = int(np.argmax(np.max(g, axis=(1, 2))))
    return {'band_hz': float(band_hz),
            'tracking_error_pct': float(100.0 * np.max(np.abs(diag - ell[:, None])
                                                       / np.abs(ell)[:, None])),
            'residual_coupling_pct': coupling(loop) if n > 1 else 0.0,
            'plant_coupling_pct': coupling(p) if n > 1 else 0.0,
            'gain_peak': float(np.max(g)), 'gain_peak_hz': float(f_all[k])}


# ----------------------------------------------------------------------------- one record
#: Largest |correlation| between two commands the identification takes without a warning:
#: beyond it the record cannot tell one actuator's effect from another's.
CORRELATED_INPUTS = 0.5


def identify_record(u, y, fs_hz: float, validation_fraction: float = 1.0 / 3.0,
                    n_max: int = 12, horizon: int = 30, band_hz: float = None,
                    progress=None) -> tuple:
    """Identify the N x N plant from one record of simultaneous excitation.

    ``u``, ``y``: the N commands and N measured displacements (samples x N).  The first
    part of the record trains every order ``1..n_max``, the last ``validation_fraction``
    chooses it (:func:`identify_multichannel`).  Returns ``(model, report)``; ``report``
    holds the choice, the validation fit per output (simulation NRMSE [%], the held-out
    part's initial state fitted), the inputs' largest correlation, and the cross-coupling
    over ``band_hz`` (default: the band that holds 99.5 % of the commands' power).
    """
    u, y = _as_2d(u), _as_2d(y)
    if u.shape != y.shape:
        raise ValueError(f'{u.shape[1]} command and {y.shape[1]} measured channels of '
                         f'{u.shape[0]} / {y.shape[0]} samples: give one of each per actuator')
    n_ch = u.shape[1]
    split = split_point(u.shape[0], validation_fraction)
    if min(split, u.shape[0] - split) < 2 * int(horizon) + 10:
        raise ValueError(f'{u.shape[0]} samples are too few for a horizon of {horizon} '
                         'samples on both the training and the held-out part; record longer')
    band = (float(band_hz) if band_hz
            else max(excited_band_hz(u[:, j], fs_hz) for j in range(n_ch)))
    if not 0.0 < band <= fs_hz / 2:
        raise ValueError(f'band {band:g} Hz must lie in (0, fs/2 = {fs_hz / 2:g}] Hz')
    train, val = [(u[:split], y[:split])], [(u[split:], y[split:])]
    model = identify_multichannel(train, val, fs_hz, n_max=n_max, horizon=horizon,
                                  progress=progress)
    corr = np.corrcoef(u.T) if n_ch > 1 else np.ones((1, 1))
    off = np.abs(corr - np.diag(np.diag(corr)))
    worst = np.unravel_index(int(np.argmax(off)), off.shape)
    row = next(r for r in model.selection['grid'] if r['order'] == model.order)
    report = {'method': 'state-space subspace (PO-MOESP) + simulation-error B, D',
              'n_channels': n_ch, 'fs_hz': float(fs_hz), 'samples': int(u.shape[0]),
              'split': int(split), 'validation_fraction': float(validation_fraction),
              'order': model.order, 'horizon': int(horizon), 'order_max': int(n_max),
              'criterion': model.selection['criterion'],
              'order_at_edge': model.order == max(r['order'] for r in model.selection['grid']),
              'validation': {'fit': float(f"{row['fit']:.6g}"),
                             'nrmse_pct': output_nrmse_pct(model, u[split:], y[split:])},
              'input_correlation_max': round(float(off[worst]), 4),
              'input_correlation_pair': [int(worst[0]), int(worst[1])],
              'cross_coupling': cross_coupling(model, band),
              'grid': [{k: (float(f'{v:.6g}') if isinstance(v, float) else v)
                        for k, v in r.items()} for r in model.selection['grid']]}
    report['cross_coupling']['dc_rel_max'], report['cross_coupling']['peak_rel_max'] = (
        _off_diagonal_max(report['cross_coupling'][k]) for k in ('dc_rel', 'peak_rel'))
    report['warnings'] = identification_warnings(report)
    return model, report


def _off_diagonal_max(matrix) -> float:
    m = np.asarray(matrix, float)
    if m.shape[0] < 2:
        return 0.0
    return float(np.max(m[~np.eye(m.shape[0], dtype=bool)]))


def output_nrmse_pct(model: MimoModel, u, y) -> list:
    """Return the simulation NRMSE [%] of each output over one record (initial state fitted)."""
    u, y = _as_2d(u), _as_2d(y)
    resid = y - model.simulate(u)
    phx = _free_response(model.a, model.c, u.shape[0])
    resid = (resid.ravel() - phx @ _lsq(phx, resid.ravel())).reshape(y.shape)
    std = np.std(y, axis=0)
    return [round(float(100.0 * np.sqrt(np.mean(resid[:, i] ** 2)) / std[i]), 4)
            if std[i] > 0 else float('nan') for i in range(y.shape[1])]


def identification_warnings(report: dict) -> list:
    """Return the warnings of an identification report (correlated inputs, order at edge)."""
    out = []
    if report['input_correlation_max'] > CORRELATED_INPUTS:
        i, j = report['input_correlation_pair']
        out.append(f'commands {i + 1} and {j + 1} correlate by '
                   f'{report["input_correlation_max"]:.2f}: the record cannot tell their '
                   'effects apart (an RTHS run moves the actuators together); excite every '
                   'actuator with its own uncorrelated signal (BLWN or multisine per actuator)')
    if report['order_at_edge']:
        out.append(f'the chosen order {report["order"]} is the largest tried; raise '
                   '--order-max')
    if max(report['validation']['nrmse_pct']) > 20.0:
        out.append(f'poor validation fit (NRMSE {max(report["validation"]["nrmse_pct"]):.1f} '
                   '% on the held-out part): excite more, record longer, or check the columns')
    return out


def empirical_frf(u, y, fs_hz: float, seconds: float = 4.0):
    """``(f, H)``: the record's H1 estimate ``S_yu S_uu^-1`` (f x p x m), Welch segments."""
    u, y = _as_2d(u), _as_2d(y)
    nper = int(min(u.shape[0], max(256, round(seconds * fs_hz))))
    m, p = u.shape[1], y.shape[1]
    f = csd(u[:, 0], u[:, 0], fs=fs_hz, nperseg=nper)[0]
    suu = np.empty((f.size, m, m), complex)
    syu = np.empty((f.size, p, m), complex)
    for a in range(m):
        for b in range(m):
            suu[:, a, b] = csd(u[:, b], u[:, a], fs=fs_hz, nperseg=nper)[1]
        for i in range(p):
            syu[:, i, a] = csd(u[:, a], y[:, i], fs=fs_hz, nperseg=nper)[1]
    h = np.full((f.size, p, m), np.nan + 0j)
    ok = np.array([np.linalg.cond(s) < 1e8 for s in suu])
    h[ok] = syu[ok] @ np.linalg.inv(suu[ok])
    return f, h


def plot_identification(model: MimoModel, u, y, report: dict, path, title: str = '') -> str:
    """PNG of every pair's |G_ij|: the model beside the record's H1 estimate, band marked."""
    # lazy: start-up cost: matplotlib (~0.5 s), which this module needs only here
    import matplotlib
    matplotlib.use('Agg')
    # lazy: start-up cost: matplotlib (~0.5 s), which this module needs only here
    import matplotlib.pyplot as plt

    fs, band = model.fs_hz, report['cross_coupling']['band_hz']
    f, h = empirical_frf(u, y, fs)
    sel = (f > 0) & (f <= min(fs / 2, 2.0 * band))
    hm = model.freq_resp(f[sel])
    n = model.b.shape[1]
    fig, axes = plt.subplots(n, n, figsize=(4.2 * n, 3.2 * n), squeeze=False, sharex=True)
    for i in range(n):
        for j in range(n):
            ax = axes[i, j]
            ax.plot(f[sel], 20 * np.log10(np.abs(h[sel, i, j])), lw=0.7, label='record (H1)')
            ax.plot(f[sel], 20 * np.log10(np.abs(hm[:, i, j])), lw=1.0, ls='--', label='model')
            ax.axvline(band, color='k', lw=0.6, ls=':')
            rel = report['cross_coupling']['peak_rel'][i][j]
            ax.set_title(f'command {j + 1} -> measured {i + 1}'
                         + (f' ({100 * rel:.1f} % of {i + 1}->{i + 1})' if i != j else ''),
                         fontsize=9)
            ax.grid(True, alpha=0.3)
            if j == 0:
                ax.set_ylabel('|G| [dB]')
            if i == n - 1:
                ax.set_xlabel('frequency [Hz]')
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(f'{title}\nstate-space order {model.order}, fs {fs:g} Hz; validation NRMSE '
                 + ', '.join(f'{v:.2f}' for v in report['validation']['nrmse_pct']) + ' %',
                 fontsize=9)
    fig.tight_layout()
    with atomic_open(path, 'wb') as handle:
        fig.savefig(handle, format='png', dpi=100)
    plt.close(fig)
    return str(path)


def save_plant(path, model: MimoModel, report: dict) -> str:
    """Atomically write the N x N plant file: the model (:meth:`MimoModel.to_dict`) + report."""
    doc = dict(model.to_dict(), n_channels=int(model.b.shape[1]), units='m',
               cross_coupling=report['cross_coupling'], identification=_plain(report))
    path = os.fspath(path)
    with atomic_open(path) as handle:
        handle.write(yaml.safe_dump(_plain(doc), default_flow_style=None, sort_keys=False,
                                    width=100))
    return path


def model_from_dict(data: dict, where: str = 'plant') -> MimoModel:
    """Build the N x N model of a plant file (:func:`save_plant`); ValueError names the field."""
    if not isinstance(data, dict) or data.get('kind') != 'state_space':
        raise ValueError(f'{where}: not an N x N plant file (kind state_space); write one with '
                         'rths identify --channels N')
    fs = data.get('fs_hz')
    if isinstance(fs, bool) or not isinstance(fs, (int, float)) or not (
            math.isfinite(fs) and fs > 0):
        raise ValueError(f'{where}: field fs_hz = {fs!r}; give the sampling rate in Hz, > 0')
    mats = {}
    for field in ('a', 'b', 'c', 'd'):
        try:
            mats[field] = np.atleast_2d(np.asarray(data[field], dtype=float))
        except KeyError:
            raise ValueError(f'{where}: field {field} missing; re-run rths identify '
                             '--channels N') from None
        except (TypeError, ValueError):
            raise ValueError(f'{where}: field {field} must be a matrix of numbers') from None
        if not np.all(np.isfinite(mats[field])):
            raise ValueError(f'{where}: field {field} holds nan/inf; re-run rths identify')
    n = mats['a'].shape[0]
    shapes = {'a': (n, n), 'b': (n, None), 'c': (None, n), 'd': (mats['c'].shape[0],
                                                                 mats['b'].shape[1])}
    for field, want in shapes.items():
        got = mats[field].shape
        if any(w is not None and w != g for w, g in zip(want, got, strict=True)):
            raise ValueError(f'{where}: field {field} has the shape {got}, not '
                             f'{tuple("N" if w is None else w for w in want)}; re-run rths '
                             'identify --channels N')
    return MimoModel(mats['a'], mats['b'], mats['c'], mats['d'], float(fs))


def df2t_step(z, x, b, a):
    """One sample of the filter ``b / a`` (``a[0] = 1``) in direct form II transposed.

    ``x`` (any shape) is the input of the sample, ``z`` its states (``x.shape + (order,)``),
    updated in place; returns the output.  Vectorised over independent runs and channels.
    """
    y = b[0] * x + z[..., 0]
    z[..., :-1] = z[..., 1:] + b[1:-1] * x[..., None] - a[1:-1] * y[..., None]
    z[..., -1] = b[-1] * x - a[-1] * y
    return y


class AdaptiveCorrection:
    """Per-channel adaptive gain and time shift ahead of a coupled design.

    The coupled FIR (:func:`design_coupled_fir`) makes the N x N loop ``P G`` close to the
    identity on the identified plant; on the rig's true plant each channel keeps a small
    gain and phase error of its own.  Channel i's target t_i becomes
    ``v_i = a0 t_i + a1 t_i'`` (a0 = 1, a1 = 0 at the start; ``t'`` the backward difference
    through an order-2 Butterworth low-pass at ``shift_lowpass_hz``, so the correction adds
    no gain at high frequencies, where the RTHS loop feeds the target's noise back) before
    the coupled FIR, and ``(a0, a1)`` is fitted, as the project's ``ats``
    (Chae et al. 2013, docs/adaptive.md) fits its coefficients, by least squares of the
    channel's inverse over a moving window: ``v_i = a0 y_i + a1 y_i'`` with y_i the
    measured stroke, both low-passed (Butterworth order 4, ``lowpass_hz``: the sensor noise
    above the band would bias the inverse), the window's normal equations weighted
    exponentially (time constant ``window_s``) and solved every ``every`` steps.  The
    coefficients stay within ``gain_bounds`` and ``+-shift_max_s`` and move at most
    ``rates`` (per second).  Two coefficients instead of a free FIR: the low-passed
    regressors of consecutive samples are nearly collinear, and an adapted FIR of even 3
    taps drifted along those directions into an unstable loop.

    Guards as the project's adaptive methods' (:class:`.adaptive.Guards`): a channel adapts
    only while its target's RMS (exponential window ``guard_window_s``) is at least
    ``excitation`` (the caller's units); once, so excited and after ``start_s``, its
    relative RMS tracking error over that window exceeds ``fallback_pct`` %, its correction
    returns to the identity for good (the coupled design alone; ``fallen_back``).  The
    regression pairs the corrected target of step k-1 with the measurement of step k-1 (the
    design makes y(k) follow v(k)).  Vectorised over B independent runs: arrays (B, N).
    """

    def __init__(self, batch: int, n_channels: int, fs_hz: float, lowpass_hz: float = 20.0,
                 window_s: float = 1.0, every: int = 16, gain_bounds=(0.5, 2.0),
                 shift_max_s: float = 0.005, rates=(0.2, 0.005), start_s: float = 1.0,
                 excitation: float = 0.0, guard_window_s: float = 0.5,
                 fallback_pct: float = 30.0, shift_lowpass_hz: float = 50.0):
        """Start ``batch`` x ``n_channels`` corrections at the identity."""
        shape = (int(batch), int(n_channels))
        self.fs_hz = float(fs_hz)
        self.a = np.zeros(shape + (2,))
        self.a[..., 0] = 1.0
        self.lower = np.array([gain_bounds[0], -shift_max_s], float)
        self.upper = np.array([gain_bounds[1], shift_max_s], float)
        self.every = int(every)
        self.max_step = np.asarray(rates, float) * self.every / self.fs_hz
        self._beta = 1.0 / max(1.0, window_s * fs_hz)
        self._start = int(round(start_s * fs_hz))
        self._k = 0
        b, a = butter(4, lowpass_hz, fs=fs_hz)
        self._fb, self._fa = b / a[0], a / a[0]
        m = len(b) - 1
        self._zy = np.zeros(shape + (m,))
        self._zv = np.zeros(shape + (m,))
        bd, ad = butter(2, shift_lowpass_hz, fs=fs_hz)
        self._db, self._da = bd / ad[0], ad / ad[0]
        self._zd = np.zeros(shape + (2,))
        self._t = np.zeros(shape)              # target of step k-1
        self._y = np.zeros(shape)              # filtered measured of step k-1
        self._vf = np.zeros(shape)             # filtered corrected target of step k-1
        self._gram = np.zeros(shape + (2, 3))  # windowed [phi phi' | phi v]
        self.excitation = float(excitation)
        self.fallback_pct = float(fallback_pct)
        self._alpha = 1.0 / max(1.0, guard_window_s * fs_hz)
        self._ms_t = np.zeros(shape)           # windowed mean squares: target, error
        self._ms_e = np.zeros(shape)
        self.fallen_back = np.zeros(shape, bool)

    def _filter(self, z, x, b=None, a=None):
        """One step of the order-4 low-pass (or of ``b, a``); returns y, updates ``z``."""
        if b is None:
            b, a = self._fb, self._fa
        return df2t_step(z, x, b, a)

    def step(self, target, measured=None) -> np.ndarray:
        """Corrected targets (B, N) for ``target`` (B, N); ``measured`` answers step k-1."""
        target = np.asarray(target, float)
        if measured is not None:
            self._observe(target, np.asarray(measured, float))
        rate = self._filter(self._zd, (target - self._t) * self.fs_hz, self._db, self._da)
        v = self.a[..., 0] * target + self.a[..., 1] * rate
        self._t = target
        self._vf = self._filter(self._zv, v)
        self._k += 1
        return v

    def _observe(self, target, measured):
        err = target - measured                # the design makes y(k) follow t(k)
        self._ms_t += self._alpha * (target * target - self._ms_t)
        self._ms_e += self._alpha * (err * err - self._ms_e)
        excited = (self._ms_t >= self.excitation ** 2) & (self._ms_t > 0.0)
        started = self._k > self._start
        bad = started & excited & ~self.fallen_back & (
            self._ms_e > (self.fallback_pct / 100.0) ** 2 * self._ms_t)
        if np.any(bad):
            self.fallen_back |= bad
            self.a[bad] = (1.0, 0.0)
        y = self._filter(self._zy, measured)
        if started:                            # v(k-1) against y(k-1) and its difference
            phi = np.stack([self._y, (y - self._y) * self.fs_hz], axis=-1)
            adapt = excited & ~self.fallen_back
            row = np.concatenate([phi[..., :, None] * phi[..., None, :],
                                  (phi * self._vf[..., None])[..., :, None]], axis=-1)
            self._gram += np.where(adapt[..., None, None], self._beta * (row - self._gram), 0.0)
            if self._k % self.every == 0 and np.any(adapt):
                self._fit(adapt)
        self._y = y

    def _fit(self, adapt):
        """Solve the window's 2 x 2 normal equations where ``adapt``; clip and rate-limit."""
        g = self._gram
        a11, a12, a22 = g[..., 0, 0], g[..., 0, 1], g[..., 1, 1]
        det = a11 * a22 - a12 * a12
        ok = adapt & (det > 1e-9 * a11 * a22) & (a11 > 0.0)
        det = np.where(ok, det, 1.0)
        sol = np.stack([(a22 * g[..., 0, 2] - a12 * g[..., 1, 2]) / det,
                        (a11 * g[..., 1, 2] - a12 * g[..., 0, 2]) / det], axis=-1)
        sol = np.clip(sol, self.a - self.max_step, self.a + self.max_step)
        sol = np.clip(sol, self.lower, self.upper)
        self.a = np.where(ok[..., None] & np.isfinite(sol), sol, self.a)
