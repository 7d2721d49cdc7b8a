"""Identification of a lab's actuator from one noisy record: the default of ``rths identify``.

The seed's ARX grid (:mod:`.identification`) fits the equation error, which output noise
biases, and searches no dead time unless told to.  This module builds on it:

1. **Band and pre-filter.**  Means are removed; the excited band is where the command holds
   99.5 % of its power; command and measurement pass the same zero-phase 4th-order
   Butterworth low-pass at 1.25x that band (:func:`prefilter`).  The same filter on both
   leaves their relation alone and removes the measurement noise outside the band.
2. **Held-out part.**  The first ``1 - validation_fraction`` of the record trains, the rest
   validates (:func:`split_point`); every score below is measured on the held-out part only.
3. **Dead time from the data** (:func:`estimate_delay`): low-order ARX models (na = nb =
   2..4) for every dead time up to ``max_delay_s`` are fitted on a decimated copy of the
   record, and the dead time whose model SIMULATES the validation part best is taken.
4. **Grid around it** (:func:`arx_candidates`): ARX na = 1..na_max, nb = 1..nb_max, d within
   ``delay_window`` samples of the estimate, fitted from one Gram matrix, scored by the
   simulation error on the validation part (simulated over the whole record, so the
   validation part starts from the model's own state rather than from rest).
5. **Output-error refinement** (:func:`refine_oe`): the best ARX candidates are refined by
   minimising the simulation (output) error on the training part, the prediction-error
   method for an output-error model (Ljung, System Identification, 2nd ed., sections 4.2
   and 7.3): Levenberg-Marquardt (``scipy.optimize.least_squares``) with the exact
   Jacobian (two filterings per iteration).  It is consistent under white or coloured
   output noise, where the ARX estimate is not.
6. **Order on the held-out part**: the candidate with the smallest BIC (eq. 40) of its
   validation simulation error is chosen.
7. **Validation** (:func:`validate`): the simulation NRMSE on the held-out part (raw record
   and in-band), the record's empirical frequency response (H1 estimate with its
   coherence-based standard deviation, Bendat & Piersol, Random Data, eq. 9.52) beside the
   model's, and warnings when the choice sits at an edge of its grid or the fit is poor.

Everything works at any uniform sampling rate; dead times are in samples of that rate.
"""

import dataclasses

import numpy as np
from scipy import optimize, signal

from .identification import ArxModel

#: Validation simulation NRMSE [%] (raw record) above which the fit is called poor.
POOR_FIT_NRMSE_PCT = 10.0
#: Largest in-band frequency-response error [%] of a good fit (model vs the record's FRF).
POOR_FRF_ERROR_PCT = 5.0


@dataclasses.dataclass
class IdentOptions:
    """Choices of :func:`identify_record` (the defaults are ``rths identify``'s)."""

    na_max: int = 6
    nb_max: int = 6
    max_delay_s: float = 0.1
    delay_window: int = None          # samples either side of the estimate (None: 2 ms, >= 3)
    d_min: int = None                 # explicit dead-time range instead of the estimate
    d_max: int = None
    validation_fraction: float = 1.0 / 3.0
    refine: bool = True               # output-error refinement of the best ARX candidates
    n_refine: int = 6
    prefilter: bool = True


def excited_band_hz(u, fs_hz: float, fraction: float = 0.995) -> float:
    """Frequency [Hz] below which the command holds ``fraction`` of its power."""
    u = np.asarray(u, dtype=float)
    nper = int(min(u.size, max(256, round(4 * fs_hz))))
    f, p = signal.welch(u - np.mean(u), fs=fs_hz, nperseg=nper)
    if not np.sum(p) > 0:
        raise ValueError('the command is constant: nothing to identify from')
    c = np.cumsum(p) / np.sum(p)
    return float(f[min(np.searchsorted(c, fraction), f.size - 1)])


def prefilter(x, fs_hz: float, cutoff_hz: float):
    """Zero-phase 4th-order Butterworth low-pass (none when the cut-off is near Nyquist)."""
    if cutoff_hz >= 0.4 * fs_hz:
        return np.asarray(x, dtype=float)
    sos = signal.butter(4, cutoff_hz, fs=fs_hz, output='sos')
    return signal.sosfiltfilt(sos, np.asarray(x, dtype=float))


def split_point(n: int, validation_fraction: float) -> int:
    """Index where the validation part starts (the training part is ``[:split]``)."""
    if not 0.05 <= validation_fraction <= 0.8:
        raise ValueError(f'validation fraction {validation_fraction} must lie in [0.05, 0.8]')
    return int(round(n * (1.0 - validation_fraction)))


def _lagged(u, y, na, u_lags, t0):
    """Regression ``[-y(t-1..t-na), u(t-l) for l in u_lags]`` for t >= t0, and y(t)."""
    rows = np.arange(t0, y.size)
    cols = [-y[rows - i] for i in range(1, na + 1)] + [u[rows - lag] for lag in u_lags]
    return np.column_stack(cols), y[rows]


def _solve(g, r, idx):
    """Least squares of the sub-model ``idx`` from the Gram data (column-scaled)."""
    sub = g[np.ix_(idx, idx)]
    scale = np.sqrt(np.diag(sub))
    scale[scale == 0] = 1.0
    try:
        theta = np.linalg.solve(sub / np.outer(scale, scale), r[idx] / scale) / scale
    except np.linalg.LinAlgError:
        return None
    return theta if np.all(np.isfinite(theta)) else None


def _stable(a) -> bool:
    return a.size == 1 or bool(np.max(np.abs(np.roots(a))) < 1.0)


def _sim_error(a, b, d, u, y, split):
    """Validation MSE of the model simulated over the whole record (inf if unstable)."""
    if not _stable(a):
        return np.inf
    with np.errstate(all='ignore'):
        e = y[split:] - signal.lfilter(np.r_[np.zeros(d), b], a, u)[split:]
        mse = float(np.mean(e ** 2))
    return mse if np.isfinite(mse) else np.inf


def arx_candidates(u, y, split, na_range, nb_range, d_range, progress=None):
    """ARX fits on ``[:split]`` of every (na, nb, d), scored on ``[split:]`` by simulation.

    Returns a list of ``(mse, na, nb, d, a, b)`` sorted best first (failed fits left out).
    """
    na_range, nb_range, d_range = list(na_range), list(nb_range), list(d_range)
    na_max, nb_max = max(na_range), max(nb_range)
    d_lo, d_hi = min(d_range), max(d_range)
    lags = list(range(d_lo, d_hi + nb_max))
    t0 = max(na_max, d_hi + nb_max)
    if split - t0 < 10 * (na_max + len(lags)):
        raise ValueError(f'training part of {split} samples too short for na={na_max}, '
                         f'dead time up to {d_hi} samples; record longer')
    phi, target = _lagged(u[:split], y[:split], na_max, lags, t0)
    g, r = phi.T @ phi, phi.T @ target
    out = []
    total = len(na_range) * len(nb_range) * len(d_range)
    for d in d_range:
        for na in na_range:
            for nb in nb_range:
                idx = np.r_[np.arange(na), na_max + (d - d_lo) + np.arange(nb)]
                theta = _solve(g, r, idx)
                if theta is not None:
                    a, b = np.r_[1.0, theta[:na]], theta[na:]
                    mse = _sim_error(a, b, d, u, y, split)
                    if np.isfinite(mse):
                        out.append((mse, na, nb, d, a, b))
                if progress is not None:
                    progress(len(out), total)
    out.sort(key=lambda c: c[0])
    return out


def estimate_delay(u, y, fs_hz: float, split: int, band_hz: float,
                   max_delay_s: float = 0.1) -> int:
    """Dead time [samples at fs_hz] whose low-order ARX model simulates the validation best.

    The scan runs on a copy decimated to about 10x the excited band (the band-limited,
    pre-filtered signals lose nothing), so a 0.1 s range costs the same at any rate; the
    result is the decimated dead time times the factor (refined by the grid around it).
    """
    q = max(1, int(fs_hz // (10.0 * max(band_hz, 1.0))))
    ud, yd = u[::q], y[::q]
    d_max = max(1, int(round(max_delay_s * fs_hz / q)))
    d_max = min(d_max, (split // q) // 20)
    cands = arx_candidates(ud, yd, split // q, range(2, 5), range(2, 5), range(0, d_max + 1))
    if not cands:
        raise ValueError('no stable low-order model fits the record; is the measured column '
                         'the actuator displacement, and the command its input?')
    best = {}
    for mse, _, _, d, _, _ in cands:
        best[d] = min(best.get(d, np.inf), mse)
    return int(min(best, key=best.get)) * q


def refine_oe(u, y, a0, b0, d, max_nfev: int = 60):
    """Output-error refinement of ``B/A`` (dead time d fixed) on ``(u, y)``; ``(a, b)``.

    Minimises ``sum (y - z^-d B/A u)^2`` by Levenberg-Marquardt from the ARX estimate.
    Jacobian: ``d yhat/d b_j = z^-j (1/A) u_d`` and ``d yhat/d a_i = -z^-i (1/A) yhat``.
    An unstable iterate gets a large residual, so the search stays among stable models;
    the refined model is returned only if it simulates the data better than the start.
    """
    a0, b0 = np.asarray(a0, dtype=float), np.asarray(b0, dtype=float)
    na, nb = a0.size - 1, b0.size
    ud = np.r_[np.zeros(d), u[:u.size - d]] if d else np.asarray(u, dtype=float)
    big = 1e3 * float(np.std(y)) + 1.0

    def unpack(p):
        return np.r_[1.0, p[:na]], p[na:]

    def resid(p):
        a, b = unpack(p)
        if not _stable(a):
            return np.full(y.size, big)
        return signal.lfilter(b, a, ud) - y

    def jac(p):
        a, b = unpack(p)
        x = signal.lfilter([1.0], a, ud)
        w = signal.lfilter([1.0], a, signal.lfilter(b, a, ud))
        jm = np.zeros((y.size, na + nb))
        for i in range(1, na + 1):
            jm[i:, i - 1] = -w[:-i]
        for j in range(nb):
            jm[j:, na + j] = x[:x.size - j]
        return jm

    p0 = np.r_[a0[1:], b0]
    try:
        res = optimize.least_squares(resid, p0, jac=jac, method='lm', x_scale='jac',
                                     max_nfev=max_nfev)
    except (ValueError, np.linalg.LinAlgError):
        return a0, b0
    a, b = unpack(res.x)
    if not (np.all(np.isfinite(res.x)) and _stable(a)):
        return a0, b0
    if np.sum(resid(res.x) ** 2) > np.sum(resid(p0) ** 2):
        return a0, b0
    return a, b


@dataclasses.dataclass
class Identified:
    """Result of :func:`identify_record`: the model and what a lab needs to trust it."""

    model: ArxModel
    info: dict
    warnings: list
    frf: dict


def identify_record(u, y, fs_hz: float, options: IdentOptions = None, progress=None,
                    log=None) -> Identified:
    """Identify the plant ``u -> y`` of one record (steps 1-7 of the module docstring)."""
    opt = options or IdentOptions()
    say = log or (lambda text: None)
    u = np.asarray(u, dtype=float).ravel()
    y = np.asarray(y, dtype=float).ravel()
    if u.shape != y.shape:
        raise ValueError(f'command ({u.size}) and measured ({y.size}) lengths differ')
    if not (np.all(np.isfinite(u)) and np.all(np.isfinite(y))):
        raise ValueError('the record holds nan/inf values')
    fs = float(fs_hz)
    offsets = {'command': float(np.mean(u)), 'measured': float(np.mean(y))}
    u0, y0 = u - offsets['command'], y - offsets['measured']
    band = excited_band_hz(u0, fs)
    cutoff = min(1.25 * band, 0.45 * fs)
    uf, yf = (prefilter(u0, fs, cutoff), prefilter(y0, fs, cutoff)) if opt.prefilter else (u0, y0)
    split = split_point(u.size, opt.validation_fraction)
    warnings = []
    if opt.d_min is not None or opt.d_max is not None:
        d_lo = int(opt.d_min or 0)
        d_hi = int(opt.d_max if opt.d_max is not None else d_lo)
        if d_hi < d_lo:
            raise ValueError(f'dead-time range {d_lo}..{d_hi} is empty')
        d_est = None
    else:
        d_est = estimate_delay(uf, yf, fs, split, band, opt.max_delay_s)
        w = opt.delay_window if opt.delay_window is not None else max(3, int(round(2e-3 * fs)))
        d_lo, d_hi = max(0, d_est - w), d_est + w
    say(f'identify: band 0-{band:.3g} Hz (pre-filter {cutoff:.3g} Hz), dead time '
        + (f'estimated {d_est} samples ({1e3 * d_est / fs:.2f} ms), ' if d_est is not None
           else '') + f'searched {d_lo}..{d_hi}')
    cands = arx_candidates(uf, yf, split, range(1, opt.na_max + 1), range(1, opt.nb_max + 1),
                           range(d_lo, d_hi + 1), progress=progress)
    if not cands:
        raise ValueError('no stable ARX model in the grid; check the columns (command -> '
                         'measured displacement) and the record')
    n_val = u.size - split
    scored = []
    seen = set()
    for mse, na, nb, d, a, b in cands:
        if len(seen) >= (opt.n_refine if opt.refine else 1):
            break
        if (na, nb, d) in seen:
            continue
        seen.add((na, nb, d))
        if opt.refine:
            a, b = refine_oe(uf[:split], yf[:split], a, b, d)
            mse = _sim_error(a, b, d, uf, yf, split)
        bic = np.log(mse) + np.log(n_val) * (na + nb) / n_val
        scored.append((bic, mse, na, nb, d, a, b))
    scored.sort(key=lambda s: s[0])
    _, mse, na, nb, d, a, b = scored[0]
    model = ArxModel(a=a, b=b, d=d, fs_hz=fs)
    val = validate(model, u0, y0, fs, split, band)
    if na == opt.na_max or nb == opt.nb_max:
        warnings.append(f'the chosen order na={na} nb={nb} sits at the edge of the grid '
                        f'(na, nb <= {opt.na_max}, {opt.nb_max}); widen it (--na-max/--nb-max)')
    if d in (d_lo, d_hi) and not (d == 0 and d_lo == 0):
        warnings.append(f'the chosen dead time d={d} sits at the edge of the searched range '
                        f'{d_lo}..{d_hi}; widen it (--d-min/--d-max)')
    if val['nrmse_pct'] > POOR_FIT_NRMSE_PCT or val['frf_error_pct'] > POOR_FRF_ERROR_PCT:
        warnings.append(poor_fit_text(val))
    if not model.is_stable():
        warnings.append('the chosen model is unstable')
    info = {
        'method': 'arx grid + output-error refinement' if opt.refine else 'arx grid',
        'criterion': 'bic of the validation simulation error',
        'na': na, 'nb': nb, 'd': d,
        'delay_estimate': d_est, 'd_range': [d_lo, d_hi],
        'na_max': opt.na_max, 'nb_max': opt.nb_max,
        'band_hz': band, 'prefilter_hz': cutoff if opt.prefilter else None,
        'offsets': offsets, 'n_samples': int(u.size), 'split': int(split),
        'validation_fraction': opt.validation_fraction,
        'candidates': [f'na={s[2]} nb={s[3]} d={s[4]}: validation nrmse '
                       f'{100 * np.sqrt(s[1] / np.var(yf[split:])):.3f} %' for s in scored],
        'validation': {k: v for k, v in val.items() if k != 'frf'},
        'warnings': list(warnings),
    }
    return Identified(model, info, warnings, val['frf'])


def is_poor_fit(validation: dict) -> bool:
    """True if a validation summary (:func:`validate`) calls the fit poor."""
    return (validation['nrmse_pct'] > POOR_FIT_NRMSE_PCT
            or validation['frf_error_pct'] > POOR_FRF_ERROR_PCT)


def poor_fit_text(validation: dict) -> str:
    """One line naming the poor figure and what to do."""
    return (f"poor fit: validation simulation NRMSE {validation['nrmse_pct']:.2f} % (limit "
            f"{POOR_FIT_NRMSE_PCT:g} %), largest in-band FRF error "
            f"{validation['frf_error_pct']:.2f} % (limit {POOR_FRF_ERROR_PCT:g} %); check the "
            'columns and units, record longer or with more excitation, or widen the grid')


def empirical_frf(u, y, fs_hz: float, nperseg: int = None) -> dict:
    """H1 estimate of ``u -> y`` with coherence and the standard deviation of ``|H|``.

    ``std = |H| sqrt(1 - coh) / sqrt(2 n_avg coh)`` (Bendat & Piersol, eq. 9.52; n_avg the
    number of Welch segments, 50 % overlap counted as half independent).
    """
    u = np.asarray(u, dtype=float)
    if nperseg is None:
        nperseg = int(min(u.size // 4, max(256, round(2 * fs_hz))))
    f, puy = signal.csd(u, y, fs=fs_hz, nperseg=nperseg)
    _, puu = signal.welch(u, fs=fs_hz, nperseg=nperseg)
    _, coh = signal.coherence(u, y, fs=fs_hz, nperseg=nperseg)
    n_avg = max(1.0, (u.size / nperseg - 1) * 2 / 2)
    with np.errstate(divide='ignore', invalid='ignore'):
        h = puy / puu
        std = np.abs(h) * np.sqrt(np.clip(1 - coh, 0, 1)) / np.sqrt(2 * n_avg * coh)
    return {'f_hz': f, 'h': h, 'coherence': coh, 'std': std}


def validate(model: ArxModel, u, y, fs_hz: float, split: int, band_hz: float) -> dict:
    """Fit figures of ``model`` on the validation part ``[split:]`` of a (mean-free) record.

    ``nrmse_pct``: simulation error RMS over the measured RMS (raw record, noise included);
    ``nrmse_band_pct``: the same after the in-band pre-filter; ``frf_error_pct``: largest
    ``|H_model - H_record| / |H_record|`` over the band where the coherence exceeds 0.9;
    ``frf_error_sigma``: the same error in units of the estimate's standard deviation.
    """
    sim = model.simulate(u)
    yv, sv = y[split:], sim[split:]
    nrmse = 100.0 * float(np.sqrt(np.mean((yv - sv) ** 2)) / np.std(yv))
    cutoff = min(1.25 * band_hz, 0.45 * fs_hz)
    yb, sb = prefilter(y, fs_hz, cutoff)[split:], prefilter(sim, fs_hz, cutoff)[split:]
    nrmse_band = 100.0 * float(np.sqrt(np.mean((yb - sb) ** 2)) / np.std(yb))
    frf = empirical_frf(u, y, fs_hz)
    _, hm = signal.freqz(model.num, model.a, worN=frf['f_hz'], fs=fs_hz)
    frf['h_model'] = hm
    sel = (frf['f_hz'] > 0) & (frf['f_hz'] <= band_hz) & (frf['coherence'] > 0.9)
    if np.any(sel):
        err = np.abs(hm[sel] - frf['h'][sel])
        frf_err = 100.0 * float(np.max(err / np.abs(frf['h'][sel])))
        frf_sigma = float(np.max(err / np.maximum(frf['std'][sel], 1e-300)))
    else:
        frf_err, frf_sigma = float('inf'), float('inf')
    return {'nrmse_pct': nrmse, 'nrmse_band_pct': nrmse_band, 'frf_error_pct': frf_err,
            'frf_error_sigma': frf_sigma, 'n_validation': int(yv.size), 'frf': frf}
