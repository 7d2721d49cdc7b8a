"""Compensation performance indicators of the seed (section 4.3.2).

* Time delay, eq. 42: ``tau(omega) = -arg[T(omega)] / omega`` (unwrapped phase, radians),
  averaged over the input bandwidth ``0 < f <= band``.  :func:`time_delay_ms` evaluates
  it from a model ``b/a`` in z^-1 on a uniform frequency grid; :func:`time_delay_from_data`
  from time series, with the FRF estimated by the H1 estimator
  ``H1(f) = S_dm(f)/S_dd(f)`` (cross-spectral density of desired d and measured m over
  the auto-spectral density of d, Welch averaging) and averaged over the Welch bins in
  the band.  Positive = lag, negative = lead.
* Relative RMS error, eq. 43: ``100 sqrt(sum (d_m - d_d)^2) / sqrt(sum d_d^2)`` [%].
"""

import numpy as np
from scipy import signal


def _delay_from_frf(freqs_hz, frf) -> float:
    omega = 2 * np.pi * np.asarray(freqs_hz)
    phase = np.unwrap(np.angle(frf))
    # A phase of the first bin near +-pi means a sign inversion, not a delay.
    phase -= 2 * np.pi * np.round(phase[0] / (2 * np.pi))
    return float(np.mean(-phase / omega) * 1e3)


def time_delay_ms(b, a, fs_hz: float, band_hz: float, n_points: int = 1000) -> float:
    """Mean time delay [ms] of ``b(z^-1)/a(z^-1)`` over ``0 < f <= band_hz`` (eq. 42)."""
    if not 0 < band_hz <= fs_hz / 2:
        raise ValueError(f'delay band {band_hz} Hz must lie in (0, {fs_hz / 2}] Hz')
    freqs = np.linspace(band_hz / n_points, band_hz, n_points)
    _, h = signal.freqz(np.atleast_1d(b), np.atleast_1d(a), worN=freqs, fs=fs_hz)
    return _delay_from_frf(freqs, h)


def frf_h1(desired, measured, fs_hz: float, nperseg: int = None):
    """H1 estimate of the FRF from ``desired`` to ``measured``: returns (freqs_hz, H)."""
    d = np.asarray(desired, dtype=float).ravel()
    m = np.asarray(measured, dtype=float).ravel()
    if d.shape != m.shape:
        raise ValueError(f'desired ({d.size}) and measured ({m.size}) lengths differ')
    if nperseg is None:
        nperseg = int(min(d.size, 4 * round(fs_hz)))
    f, pdm = signal.csd(d, m, fs=fs_hz, nperseg=nperseg)
    _, pdd = signal.welch(d, fs=fs_hz, nperseg=nperseg)
    with np.errstate(divide='ignore', invalid='ignore'):
        h = pdm / pdd
    return f, h


def time_delay_from_data(desired, measured, fs_hz: float, band_hz: float,
                         nperseg: int = None) -> float:
    """Mean time delay [ms] over ``0 < f <= band_hz`` from time series (H1 FRF + eq. 42)."""
    f, h = frf_h1(desired, measured, fs_hz, nperseg)
    sel = (f > 0) & (f <= band_hz) & np.isfinite(h)
    if np.count_nonzero(sel) < 2:
        raise ValueError(f'too few frequency bins in 0-{band_hz} Hz; use a longer record')
    return _delay_from_frf(f[sel], h[sel])


def relative_rms_pct(desired, measured) -> float:
    """Relative RMS error [%] of ``measured`` with respect to ``desired`` (eq. 43)."""
    d = np.asarray(desired, dtype=float).ravel()
    m = np.asarray(measured, dtype=float).ravel()
    if d.shape != m.shape:
        raise ValueError(f'desired ({d.size}) and measured ({m.size}) lengths differ')
    den = np.sqrt(np.sum(d ** 2))
    if den == 0:
        raise ValueError('desired signal is all zeros; relative RMS error is undefined')
    return float(100.0 * np.sqrt(np.sum((m - d) ** 2)) / den)


def bode(b, a, fs_hz: float, freqs_hz=None):
    """Bode data of ``b(z^-1)/a(z^-1)``: (freqs_hz, magnitude_db, phase_deg, delay_ms).

    ``delay_ms`` is the frequency-wise eq. 42 delay (nan at f = 0).
    """
    if freqs_hz is None:
        freqs_hz = np.linspace(0.0, fs_hz / 2, 1025)
    freqs_hz = np.asarray(freqs_hz, dtype=float)
    _, h = signal.freqz(np.atleast_1d(b), np.atleast_1d(a), worN=freqs_hz, fs=fs_hz)
    phase = np.unwrap(np.angle(h))
    phase -= 2 * np.pi * np.round(phase[0] / (2 * np.pi))
    with np.errstate(divide='ignore', invalid='ignore'):
        delay = np.where(freqs_hz > 0, -phase / (2 * np.pi * freqs_hz) * 1e3, np.nan)
    mag_db = 20 * np.log10(np.maximum(np.abs(h), 1e-300))
    return freqs_hz, mag_db, np.degrees(phase), delay
