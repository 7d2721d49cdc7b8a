"""Signal helpers of the discrepancy workflow: smoothing, derivatives, noise floor, NRMSE.

* States from a measured displacement: zero-phase 4th-order Butterworth
  low-pass (cut-off 3x the band holding 99.9 % of the output/input power), then
  central differences, low-passed again (slow records, band far below Nyquist).
* Spectral differentiation (:func:`spectral_derivative`): exact for a band-limited
  signal, no central-difference gain loss near the band edge (at ``f`` central
  differences keep ``sin(2 pi f / fs) / (2 pi f / fs)`` of the derivative: 76 % at
  ``fs / 5``).  A periodic record (:func:`period`) is differentiated over its whole
  periods as it is; any other record after removing the straight line through its
  end points (so its periodic extension is continuous) and with a raised-cosine
  low-pass from ``fc`` to ``1.25 fc`` -- the stated smoothing differentiator; its
  end effects stay in the first and last few per cent, which the scenarios leave
  out of every fit.
* Noise floor: the measurement noise is taken as white; its variance is the
  mean periodogram of the nominal residual above ``fs / 4`` (where the
  models' responses have rolled off), ``sigma^2 = mean |R_k|^2 / N``.
* ``NRMSE = rms(measured - predicted) / std(measured)`` on the chosen samples.
"""

import numpy as np
from scipy import signal


def band_edge(y, fs: float, fraction: float = 0.999) -> float:
    """Frequency [Hz] below which ``fraction`` of the power of ``y`` (detrended) lies."""
    y = np.asarray(y, float) - np.mean(y)
    p = np.abs(np.fft.rfft(y)) ** 2
    f = np.fft.rfftfreq(y.size, 1.0 / fs)
    c = np.cumsum(p)
    if c[-1] <= 0:
        return fs / 8
    return float(f[np.searchsorted(c, fraction * c[-1])])


def lowpass(y, fs: float, fc: float):
    """Zero-phase 4th-order Butterworth low-pass at ``fc`` [Hz]."""
    sos = signal.butter(4, min(fc, 0.45 * fs), fs=fs, output='sos')
    return signal.sosfiltfilt(sos, y)


def states(y, fs: float, fc: float = None, u=None) -> dict:
    """Smoothed displacement 'x', velocity 'v', acceleration 'a' and the cut-off 'fc'.

    Default cut-off: 3 x the band edge (99.9 % of the power) of ``y`` and of
    the input ``u`` (if given), within [5 Hz, fs / 6].
    """
    y = np.asarray(y, float)
    if fc is None:
        edge = band_edge(y, fs) if u is None else max(band_edge(y, fs), band_edge(u, fs))
        fc = float(np.clip(3.0 * edge, 5.0, fs / 6))
    x = lowpass(y, fs, fc)
    v = lowpass(np.gradient(x, 1.0 / fs), fs, fc)
    a = lowpass(np.gradient(v, 1.0 / fs), fs, fc)
    return {'x': x, 'v': v, 'a': a, 'fc': fc}


def sign_band(fs: float, fc: float, noise_var: float, v_eps: float,
              ratio: float = 0.25) -> float:
    """Widest low-pass edge [Hz] (``fc`` .. fs/6) whose velocity noise stays <= ``ratio v_eps``.

    A sign law ``tanh(v / v_eps)`` switches within a few samples at a reversal: a velocity
    smoothed to the input's band moves the switch and rounds it.  White displacement noise
    of variance ``s^2`` differentiated and band-limited to ``f`` has the velocity variance
    ``s^2 (2 pi)^2 f^3 / (3 fs / 2)``; the edge is the largest ``f`` that keeps its standard
    deviation at ``ratio v_eps`` (``ratio`` 1/4: the law's transition still resolved).
    """
    top = fs / 6.0
    if noise_var <= 0.0:
        return top
    f = ((ratio * v_eps) ** 2 * 3.0 * fs / (2.0 * (2.0 * np.pi) ** 2 * noise_var)) ** (1.0 / 3.0)
    return float(np.clip(f, fc, top))


def noise_variance(residual, fs: float, f_lo: float = None) -> float:
    """White-noise variance of ``residual`` from its periodogram above ``f_lo`` (fs/4)."""
    r = signal.detrend(np.asarray(residual, float))
    f_lo = fs / 4 if f_lo is None else f_lo
    spec = np.abs(np.fft.rfft(r)) ** 2
    f = np.fft.rfftfreq(r.size, 1.0 / fs)
    sel = (f > f_lo) & (f < 0.98 * fs / 2)
    return float(np.mean(spec[sel]) / r.size)


def nrmse(measured, predicted, mask=None) -> float:
    """``rms(measured - predicted) / std(measured)`` over ``mask`` (all samples if None)."""
    m = np.asarray(measured, float)
    p = np.asarray(predicted, float)
    if mask is not None:
        m, p = m[mask], p[mask]
    return float(np.sqrt(np.mean((m - p) ** 2)) / np.std(m))


def block_masks(n: int, n_blocks: int = 10, skip: float = 0.05):
    """Training / held-out masks: alternate time blocks after skipping ``skip`` of the record."""
    start = int(skip * n)
    idx = np.arange(n)
    block = ((idx - start) * n_blocks) // max(n - start, 1)
    train = (idx >= start) & (block % 2 == 0)
    test = (idx >= start) & (block % 2 == 1)
    return train, test


def period(u, min_periods=2, tol=1e-3):
    """Return the samples per period of a periodic record ``u`` (None if it does not repeat).

    A period P is accepted when the record holds at least ``min_periods`` of them and
    ``u[k + P] - u[k]`` is below ``tol`` of the spread of ``u`` in rms (a measured
    record repeats to within its noise: ``tol`` a few times the noise-to-signal ratio).
    """
    u = np.asarray(u, float) - np.mean(u)
    n = u.size
    if n < 8 or np.std(u) == 0:
        return None
    spec = np.fft.rfft(u, 2 * n)
    m = n // min_periods + 2     # lags up to n / min_periods can be a peak
    ac = np.fft.irfft(np.abs(spec) ** 2)[:m]
    ac /= ac[0] * (n - np.arange(m)) / n     # per overlapping sample: 2 periods reach 1 too
    lags = np.flatnonzero((ac[1:-1] > ac[:-2]) & (ac[1:-1] >= ac[2:]) & (ac[1:-1] > 0.5)) + 1
    for p in lags:
        if p >= 4 and np.sqrt(np.mean((u[p:] - u[:-p]) ** 2)) < tol * np.std(u):
            return int(p)
    return None


def spectral_derivative(y, fs, order=1, fc=None, periodic=False):
    """``order``-th time derivative of ``y`` by spectral differentiation (see the module doc).

    ``fc`` [Hz] (None: no low-pass) is the edge of the raised-cosine taper that
    ends at ``1.25 fc``; ``periodic``: ``y`` holds whole periods (no line removed).
    """
    y = np.asarray(y, float)
    n = y.size
    t = np.arange(n)
    line = np.zeros(n) if periodic else y[0] + (y[-1] - y[0]) * t / max(n - 1, 1)
    r = y - line
    f = np.fft.rfftfreq(n, 1.0 / fs)
    h = (2j * np.pi * f) ** order
    if n % 2 == 0 and order % 2 == 1:
        h[-1] = 0.0     # the Nyquist line has no defined odd derivative
    if fc is not None:
        w = np.clip((f - fc) / (0.25 * fc), 0.0, 1.0)
        h = h * 0.5 * (1 + np.cos(np.pi * w))
    d = np.fft.irfft(np.fft.rfft(r) * h, n)
    if order == 0:
        d += line
    elif order == 1 and not periodic:
        d += (y[-1] - y[0]) * fs / max(n - 1, 1)
    return d


def spectral_states(x, fs, fc, periodic=False):
    """Displacement, velocity, acceleration of ``x`` band-limited to ``fc`` (spectral)."""
    return {k: spectral_derivative(x, fs, order, fc, periodic)
            for k, order in (('x', 0), ('v', 1), ('a', 2))}
