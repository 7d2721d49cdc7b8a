"""The NASA Disruptive Tuned Mass (DTM) damper model of the seed (chapter 5).

Model (seed eq. 44-47)::

    m_d * xdd_d + c_1 * xd_d2s + k_1 * x_d2s + (c_v * xd_d2s + k_v * x_d2s) = 0     (44)
    m_d * xdd_d + c_d * xd_d2s + k_d * x_d2s = 0,  c_d = c_1 + c_v, k_d = k_1 + k_v  (45)
    m_d * xdd_d2s + c_d * xd_d2s + k_d * x_d2s = -m_d * xdd_s                       (46)
    T_DTM(s) = X_d2s(s) / Xdd_s(s) = -m_d / (m_d s^2 + c_d s + k_d)                  (47)

``x_d2s`` is the moving mass's displacement relative to the supporting frame,
``xdd_s`` the frame's absolute acceleration, ``xdd_d = xdd_d2s + xdd_s`` the
moving mass's absolute acceleration.  The force the damper exerts on its frame
(what the load cells under the frame legs measure, less the frame's own
inertia) is ``c_d * xd_d2s + k_d * x_d2s = -m_d * xdd_d``.

Natural frequency and damping ratio (seed eq. 48-49, with the evident
``f_n = omega_n / (2 pi)``): ``omega_n = sqrt(k_d / m_d)``,
``zeta = c_d / (2 m_d omega_n)``.

:meth:`DTMParameters.state_space` is eq. 46 as a state-space model, written once here
for the simulated plant (rths_actuator_bridge.simulated) and the numerical reference
(:class:`.reference.DTMSpecimen`).
"""

from dataclasses import dataclass
import math

import numpy as np

#: The configuration the seed's RTHS tests use (section 6.2) and the default specimen.
SEED_CONFIGURATION = 'valve4'
#: The configurations of the seed's numerical studies (tables 6-8, chapter 7): with and
#: without the valve.
STUDY_CONFIGURATIONS = (SEED_CONFIGURATION, 'novalve')

#: Mass of the DTM's supporting frame: 250.0 lbm (seed section 5.1) in kg.
FRAME_MASS_KG = 250.0 * 0.45359237


@dataclass(frozen=True)
class DTMParameters:
    """Mass [kg], damping [N s/m] and stiffness [N/m] of one DTM configuration."""

    m_d: float
    c_d: float
    k_d: float

    @property
    def omega_n(self) -> float:
        """Natural circular frequency [rad/s] (eq. 48)."""
        return math.sqrt(self.k_d / self.m_d)

    @property
    def f_n(self) -> float:
        """Natural frequency [Hz]."""
        return self.omega_n / (2.0 * math.pi)

    @property
    def zeta(self) -> float:
        """Damping ratio [-] (eq. 49)."""
        return self.c_d / (2.0 * self.m_d * self.omega_n)

    def state_space(self, mass_error: float = 0.0):
        """Return ``(A, B)`` of eq. 46 with an extra force ``f`` on the moving mass.

        State ``[x_d2s, xd_d2s]``, inputs ``[xdd_s, f]``::

            (m_d + dm) xdd_d2s = -(m_d + dm) xdd_s - c_d xd_d2s - k_d x_d2s - f

        The force on the frame is ``c_d xd_d2s + k_d x_d2s + f`` (:meth:`frame_force`).
        """
        m = self.m_d + float(mass_error)
        if not m > 0:
            raise ValueError(f'mass_error {mass_error} kg leaves no moving mass')
        a = np.array([[0.0, 1.0], [-self.k_d / m, -self.c_d / m]])
        b = np.array([[0.0, 0.0], [-1.0, -1.0 / m]])
        return a, b

    def frame_force(self, rel_disp, rel_vel):
        """Return the force [N] the damper exerts on its frame, ``c_d xd_d2s + k_d x_d2s``."""
        return self.c_d * rel_vel + self.k_d * rel_disp

    @classmethod
    def from_frequency(cls, m_d: float, f_n: float, zeta: float) -> "DTMParameters":
        """Build from mass [kg], natural frequency [Hz] and damping ratio [-]."""
        omega = 2.0 * math.pi * f_n
        return cls(m_d=m_d, c_d=2.0 * zeta * m_d * omega, k_d=m_d * omega**2)


#: Table 4 of the seed: identified DTM properties per valve configuration.
#: The table also lists zeta [%] and f_n [Hz]; those follow from m, c, k.
TABLE4 = {
    'valve1': DTMParameters(m_d=258.32, c_d=1915.6, k_d=93476.0),
    'valve2': DTMParameters(m_d=258.35, c_d=928.76, k_d=82842.0),
    'valve3': DTMParameters(m_d=258.35, c_d=644.0, k_d=81061.0),
    'valve4': DTMParameters(m_d=258.35, c_d=491.6, k_d=80810.0),
    'novalve': DTMParameters(m_d=257.55, c_d=70.025, k_d=80943.0),
}

#: Table 4's printed damping ratio [%] and natural frequency [Hz], kept for tests.
TABLE4_PRINTED = {
    'valve1': (19.67, 3.00),
    'valve2': (10.17, 2.81),
    'valve3': (7.13, 2.78),
    'valve4': (5.38, 2.81),
    'novalve': (0.769, 2.81),
}


def dtm_configuration(name: str) -> DTMParameters:
    """Return the Table 4 parameters of ``name`` (valve1..valve4, novalve)."""
    try:
        return TABLE4[name]
    except KeyError:
        raise ValueError(
            f"unknown DTM configuration {name!r}; use one of {', '.join(TABLE4)}") from None
