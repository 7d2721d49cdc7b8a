"""Continuous-time servo-hydraulic actuator models of the seed (Table 1, eq. 3).

``T(s) = K / prod_i (s - p_i)`` with ``K = prod_i (-p_i)`` so that the DC gain
is exactly 1, as eq. 3 states.  Table 1 prints K = 1.155e6 (3-pole) and
3.834e8 (4-pole); with the printed poles prod(-p_i) is 1.109e6 and 3.750e8,
so the printed gains would give a DC gain of 1.042 and 1.022.  We follow the
equation (unit DC gain) and keep the printed values for reference only.
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
