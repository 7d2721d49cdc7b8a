"""Test signals: band-limited white noise (BLWN), the seed's excitation of choice.

The seed drives the actuator (chapter 4), the DTM (chapter 5) and the tuning
study (section 7.2) with BLWN described by a band ``0~f_max`` Hz and a peak
amplitude.  :func:`blwn` builds such a signal: Gaussian white noise, ideal
band-pass in the frequency domain (zero phase, so no transient at the start),
scaled so that ``max(abs(x))`` equals the requested peak.
"""

import numpy as np


def blwn(duration_s: float, fs_hz: float, band_hz, peak: float, rng=None,
         taper_s: float = 0.0) -> np.ndarray:
    """Return ``round(duration_s * fs_hz)`` samples of band-limited white noise.

    ``band_hz`` is ``f_max`` (band 0~f_max) or a ``(f_min, f_max)`` pair in Hz;
    ``peak`` is the largest absolute value of the result (same unit as wanted,
    e.g. metres); ``rng`` is a ``numpy.random.Generator`` or a seed;
    ``taper_s`` fades the first and last seconds in/out with a half cosine so
    an actuator starts and ends at rest.
    """
    n = int(round(duration_s * fs_hz))
    if n < 4:
        raise ValueError(
            f'BLWN duration {duration_s} s at {fs_hz} Hz gives {n} samples; need >= 4')
    f_lo, f_hi = (0.0, float(band_hz)) if np.isscalar(band_hz) else map(float, band_hz)
    if not 0.0 <= f_lo < f_hi:
        raise ValueError(f'BLWN band ({f_lo}, {f_hi}) Hz must satisfy 0 <= f_min < f_max')
    if f_hi > fs_hz / 2:
        raise ValueError(f'BLWN f_max {f_hi} Hz is above the Nyquist frequency {fs_hz / 2} Hz')
    rng = np.random.default_rng(rng)
    spectrum = np.fft.rfft(rng.standard_normal(n))
    freqs = np.fft.rfftfreq(n, d=1.0 / fs_hz)
    spectrum[(freqs < f_lo) | (freqs > f_hi)] = 0.0
    spectrum[0] = 0.0  # zero mean
    x = np.fft.irfft(spectrum, n)
    if taper_s > 0:
        m = min(int(round(taper_s * fs_hz)), n // 2)
        ramp = 0.5 * (1 - np.cos(np.linspace(0.0, np.pi, m)))
        x[:m] *= ramp
        x[n - m:] *= ramp[::-1]
    top = np.max(np.abs(x))
    if top == 0:
        raise ValueError(f'BLWN band ({f_lo}, {f_hi}) Hz holds no frequency bin at this length')
    return x * (peak / top)
