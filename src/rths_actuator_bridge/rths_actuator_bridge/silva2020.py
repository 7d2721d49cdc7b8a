"""Control plant of the RTHS benchmark problem (Silva et al. 2020, MSSP 135, 106381).

Servo-valve, actuator and the physical specimen (an SDOF m_e, c_e, k_e) of the
benchmark, in the form of its Simulink model (paper section 4.2, Table 2)::

    e     = g u - x                                  (inner servo loop, g = gain)
    v     = a1b0 / (s^2 + b1 s + b2) e               (servo-valve)
    F     = 1 / (s + a3) (v - a2 s x)                (actuator, natural velocity feedback)
    x     = 1 / (m_e s^2 + c_e s + k_e) F            (specimen)

so that ``x / u = G(s) = g a1b0 / [(s^2 + b1 s + b2)((s + a3)(m_e s^2 + c_e s + k_e)
+ a2 s) + a1b0]``.  The force the load cell measures is ``F = m_e x'' + c_e x' + k_e x``.

Uncertainty (paper section 4.3): normal draws of b1, b2, a3 and k_e about the nominal
values with the standard deviations of :data:`SIGMA`; ``c_e`` follows from the drawn
``k_e`` with the nominal damping ratio.

Sensors and converters (paper section 4.2): band-limited white noise of standard
deviation :data:`DISPLACEMENT_NOISE_M` and :data:`FORCE_NOISE_N` per sample at 4096 Hz
(the Simulink noise powers 6.25e-14 m^2 s and 1.16e-3 N^2 s over 1/4096 s); the
controller's A/D and D/A converters quantise to :data:`QUANTUM` and saturate at
``+-`` :data:`SATURATION` (:func:`converter`).
"""

from dataclasses import dataclass, replace
import math

import numpy as np

#: Loop rate of the benchmark [Hz].
FS_HZ = 4096.0
#: Std of the displacement sensor noise [m] (sqrt(6.25e-14 * 4096)).
DISPLACEMENT_NOISE_M = math.sqrt(6.25e-14 * FS_HZ)
#: Std of the force sensor noise [N] (sqrt(1.16e-3 * 4096)).
FORCE_NOISE_N = math.sqrt(1.16e-3 * FS_HZ)
#: A/D and D/A quantisation interval (18-bit channel) and saturation limit.
QUANTUM = 2.0 ** -18
SATURATION = 3.8


@dataclass(frozen=True)
class Silva2020Params:
    """Parameters of the control plant (Table 2 of the benchmark; SI units)."""

    gain: float = 1.0261
    a1b0: float = 2.1283e13
    a2: float = 4.2297e6
    b1: float = 425.0
    b2: float = 9.9976e4
    a3: float = 3.3
    m_e: float = 29.13
    k_e: float = 1.19e6
    zeta_e: float = 0.0097

    @property
    def c_e(self) -> float:
        """Specimen damping [N s/m] from ``zeta_e``: ``2 zeta_e sqrt(k_e m_e)``."""
        return 2.0 * self.zeta_e * math.sqrt(self.k_e * self.m_e)


#: Standard deviations of the uncertain parameters (paper section 4.3).
SIGMA = {'b1': 3.3, 'b2': 3.3e3, 'a3': 1.3, 'k_e': 50e3}


def perturbed(rng: np.random.Generator, nominal: Silva2020Params = None) -> Silva2020Params:
    """One random draw of the uncertain parameters (:data:`SIGMA`) about ``nominal``."""
    nom = nominal or Silva2020Params()
    return replace(nom, **{k: getattr(nom, k) + s * rng.standard_normal()
                           for k, s in SIGMA.items()})


def transfer_function(p: Silva2020Params = None):
    """``(num, den)`` of ``G(s) = x / u`` in descending powers of s."""
    p = p or Silva2020Params()
    valve = np.array([1.0, p.b1, p.b2])
    spec = np.polymul([1.0, p.a3], [p.m_e, p.c_e, p.k_e])
    spec = np.polyadd(spec, [p.a2, 0.0])
    den = np.polyadd(np.polymul(valve, spec), [p.a1b0])
    return np.array([p.gain * p.a1b0]), den


def state_space(p: Silva2020Params = None):
    """Continuous ``(A, B, C, D)`` with state ``[v, v', F, x, x']``, input u [m].

    Outputs (rows of C, D): displacement x [m], velocity [m/s], acceleration [m/s^2],
    force F [N].
    """
    p = p or Silva2020Params()
    a = np.zeros((5, 5))
    a[0, 1] = 1.0
    a[1] = [-p.b2, -p.b1, 0.0, -p.a1b0, 0.0]      # v'' = a1b0 (g u - x) - b1 v' - b2 v
    a[2] = [1.0, 0.0, -p.a3, 0.0, -p.a2]          # F' = v - a2 x' - a3 F
    a[3, 4] = 1.0
    a[4] = [0.0, 0.0, 1.0 / p.m_e, -p.k_e / p.m_e, -p.c_e / p.m_e]
    b = np.zeros((5, 1))
    b[1, 0] = p.a1b0 * p.gain
    c = np.zeros((4, 5))
    c[0, 3] = 1.0
    c[1, 4] = 1.0
    c[2] = a[4]
    c[3, 2] = 1.0
    return a, b, c, np.zeros((4, 1))


def channel_model(p: Silva2020Params = None):
    """Return ``(A, B, C, D)`` in the simulated plant's layout: inputs [u, f_c], CHANNELS.

    The table channels are the specimen's displacement, velocity and acceleration, the
    force is the actuator force F; the DTM channels (rel_disp, rel_vel) are zero and the
    friction input has no effect.
    """
    a, b1, c4, _ = state_space(p)
    b = np.hstack([b1, np.zeros((5, 1))])
    c = np.zeros((6, 5))
    c[0:3] = c4[0:3]
    c[5] = c4[3]
    return a, b, c, np.zeros((6, 2))


def converter(x):
    """A/D or D/A converter of the benchmark: saturate at +-3.8, quantise to 2^-18."""
    return np.round(np.clip(x, -SATURATION, SATURATION) / QUANTUM) * QUANTUM


#: Simulated-backend parameters of the benchmark plant (for ``bridge.yaml``).
BRIDGE_PARAMS = {'actuator_model': 'silva2020', 'fs_hz': FS_HZ, 'specimen': 'none',
                 'displacement_noise_m': DISPLACEMENT_NOISE_M, 'force_noise_n': FORCE_NOISE_N,
                 'adc_bits': 0, 'daq_filter_hz': 0.0}
