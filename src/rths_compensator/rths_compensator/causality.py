"""Is the measured signal the response to the command? It must lag it, never lead it.

An identification record with its ``command`` and ``measured`` columns swapped
fits just as well, and identifies the inverse plant: a compensator designed on it
doubles the actuator's delay instead of cancelling it.  A physical actuator's
response lags its command, so the lag at which the two correlate best
(:func:`response_lag_s`) is positive; :func:`check_causality` refuses a record
whose measured signal leads.
"""

import numpy as np

#: Lags [s] searched on either side of zero (the actuators of interest lag 1-50 ms).
MAX_LAG_S = 0.25


def response_lag_s(command, measured, fs_hz: float) -> float:
    """Lag [s] of ``measured`` behind ``command`` at their largest cross-correlation."""
    u = np.asarray(command, dtype=float) - np.mean(command)
    y = np.asarray(measured, dtype=float) - np.mean(measured)
    n = u.size
    size = 1 << int(np.ceil(np.log2(2 * n)))
    xc = np.fft.irfft(np.conj(np.fft.rfft(u, size)) * np.fft.rfft(y, size), size)
    m = min(n - 1, int(MAX_LAG_S * fs_hz))
    lags = np.r_[np.arange(-m, 0), np.arange(0, m + 1)]
    values = np.r_[xc[size - m:], xc[:m + 1]]
    return float(lags[int(np.argmax(np.abs(values)))] / fs_hz)


def check_causality(command, measured, fs_hz: float, where: str) -> float:
    """Return the response lag [s]; ValueError if ``measured`` leads ``command`` (swapped)."""
    lag = response_lag_s(command, measured, fs_hz)
    if lag < 0:
        raise ValueError(f'{where}: the measured signal leads the command by {-lag * 1e3:.2f} ms '
                         '(their best cross-correlation); an actuator responds after its '
                         'command, so the columns look swapped: command is what was sent, '
                         'measured what the actuator did')
    return lag
