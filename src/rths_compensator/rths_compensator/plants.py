"""Continuous-time servo-hydraulic actuator models of the seed (Table 1, eq. 3).

``T(s) = K / prod_i (s - p_i)`` with ``K = prod_i (-p_i)`` so that the DC gain
is exactly 1, as eq. 3 states.  Table 1 prints K = 1.155e6 (3-pole) and
3.834e8 (4-pole); with the printed poles prod(-p_i) is 1.109e6 and 3.750e8,
so the printed gains would give a DC gain of 1.042 and 1.022.  We follow the
equation (unit DC gain) and keep the printed values for reference only.

Discrete-time models (:func:`discrete_actuator`) use zero-order hold (ZOH) at the
controller rate, in the project's timing convention: at step k the command u_k is
written and held for one sample, and the measurement labelled k is read at the END of
that sample.  The ZOH transfer function ``B(z^-1) = c1 z^-1 + c2 z^-2 + ...`` over
``A(z^-1)`` is therefore returned WITHOUT its one-sample delay, as
``(c1 + c2 z^-1 + ...)/A``: dead time d = 0, as the seed found for its ARX model
(section 4.3.1.2, eq. 5-6).

Appendix I: with relative degree >= 3 (both models), one ZOH zero leaves the unit
circle when the sampling frequency exceeds a threshold (Astrom et al. 1984).
:func:`unstable_zero_threshold_hz` finds it by root bracketing of
``max|zero|(fs) - 1``; it gives 41.1 Hz (3-pole) and 42.1 Hz (4-pole), matching the
seed's ~41 Hz and ~42 Hz (Figure I.1).
"""

import numpy as np

#: Table 1 poles [rad/s].  The 4-pole model prints +186.346j and -186.34j for
#: one pair; a real system has conjugate poles, so 186.34 is used for both.
TABLE1_POLES = {
    '3pole': np.array([-128.06, -32.08 + 87.34j, -32.08 - 87.34j]),
    '4pole': np.array([-119.39 + 186.34j, -119.39 - 186.34j,
                       -37.77 + 78.93j, -37.77 - 78.93j]),
}

#: Table 1 gains as printed (for comparison only; the models use prod(-p)).
TABLE1_GAIN_PRINTED = {'3pole': 1.155e6, '4pole': 3.834e8}


def actuator_poles(kind: str) -> np.ndarray:
    """Poles [rad/s] of the Table 1 model ``kind`` ('3pole' or '4pole')."""
    try:
        return TABLE1_POLES[kind].copy()
    except KeyError:
        raise ValueError(f"unknown actuator model {kind!r}; use '3pole' or '4pole'") from None


def continuous_actuator(kind: str = '3pole'):
    """Return (num, den) polynomial coefficients in s of the unit-DC-gain model."""
    poles = actuator_poles(kind)
    den = np.real(np.poly(poles))
    gain = float(np.real(np.prod(-poles)))
    return np.array([gain]), den


def discrete_actuator(kind: str = '3pole', fs_hz: float = 1024.0):
    """ZOH discretisation of the Table 1 model at ``fs_hz``: ``(b, a)`` in powers of z^-1.

    Convention (see module docstring): the ZOH one-sample delay is removed, so
    ``y_k = (b0 u_k + b1 u_{k-1} + ...) - (a1 y_{k-1} + ...)`` with ``a[0] = 1``;
    the DC gain ``sum(b)/sum(a)`` is 1.
    """
    if not fs_hz > 0:
        raise ValueError(f'sampling frequency must be > 0 Hz, got {fs_hz}')
    num, den = continuous_actuator(kind)
    # lazy: start-up cost: SciPy (~1.5 s) for every `rths` command (the CLI lists this)
    from scipy import signal

    bz, az, _ = signal.cont2discrete((num, den), 1.0 / float(fs_hz), method='zoh')
    bz = np.asarray(bz, dtype=float).ravel()
    az = np.asarray(az, dtype=float).ravel()
    # ZOH of a strictly proper system: the z^0 coefficient is zero (round-off only).
    b = bz[1:] / az[0]
    a = az / az[0]
    return b, a


def discrete_zeros(kind: str, fs_hz: float) -> np.ndarray:
    """Zeros (in z) of the ZOH-discretised model ``kind`` at ``fs_hz``."""
    b, _ = discrete_actuator(kind, fs_hz)
    return np.roots(np.trim_zeros(b, 'f'))


def max_zero_modulus(kind: str, fs_hz: float) -> float:
    """Largest zero modulus of the ZOH-discretised model (> 1: non-minimum phase)."""
    return float(np.max(np.abs(discrete_zeros(kind, fs_hz))))


def unstable_zero_threshold_hz(kind: str = '3pole', lo_hz: float = 5.0,
                               hi_hz: float = 1024.0) -> float:
    """Return the rate [Hz] above which the ZOH model ``kind`` has a zero outside |z| = 1.

    Appendix I of the seed reports ~41 Hz (3-pole) and ~42 Hz (4-pole).
    """
    def excess(fs):
        return max_zero_modulus(kind, fs) - 1.0

    if excess(lo_hz) >= 0 or excess(hi_hz) <= 0:
        raise ValueError(f'no unstable-zero threshold for {kind} between {lo_hz} and {hi_hz} Hz')
    # lazy: start-up cost: scipy.optimize, needed by this study function only
    from scipy import optimize

    return float(optimize.brentq(excess, lo_hz, hi_hz, xtol=1e-6))
