"""Signal helpers of the discrepancy workflow: smoothing, derivatives, noise floor, NRMSE.

* States from a measured displacement: zero-phase 4th-order Butterworth
  low-pass (cut-off 3x the band holding 99.9 % of the output/input power), then
  central differences, low-passed again.
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
