"""Magnetorheological (MR) damper: the phenomenological Bouc-Wen model of Spencer et al. (1997).

Spencer, Dyke, Sain and Carlson (1997), "Phenomenological model for
magnetorheological dampers", J. Eng. Mech. 123(3), 230-238, eq. 7-12::

    F  = c1 y' + k1 (x - x0)
    z' = -gamma |x' - y'| z |z|^(n-1) - beta (x' - y') |z|^n + A (x' - y')
    y' = (alpha z + c0 x' + k0 (x - y)) / (c0 + c1)
    alpha = alpha_a + alpha_b u,  c1 = c1a + c1b u,  c0 = c0a + c0b u
    u' = -eta (u - v)

``x`` is the damper stroke [m], ``v`` the command voltage [V].  At a
constant voltage the filter has settled, ``u = v``.  The accumulator preload
``-k1 x0`` is present at rest, and a lab tares its load cell with the damper at
rest: the force returned here is ``F + k1 x0`` (zero at rest).

:data:`SPENCER_1997` holds the parameters identified in that paper (its
prototype damper, 0-2.25 V), in SI units.  ``rths fit-mr`` (docs/bench/mr_fit.json)
fits the same model to the sinusoid tests of another damper (0-1 A).

:class:`MRDamper` integrates the internal states ``(z, y)`` with RK4 over
sub-steps, for a stroke given at the sub-step ends (position and velocity,
linear in between).  :class:`MRSpecimen` is the damper on a perfect actuator
(stroke = command; velocity by a second-order backward difference), the
specimen of the whole-numerical reference (:func:`simulate_mr_reference`).
"""

from dataclasses import asdict, dataclass
import math

from .reference import StrokeSpecimen, coupled_rths
from .substructure import make_substructure


@dataclass(frozen=True)
class MRParameters:
    """Parameters of the Spencer et al. (1997) model, SI units (N, m, s, V)."""

    c0a: float      # [N s/m]
    c0b: float      # [N s/(m V)]
    k0: float       # [N/m]
    c1a: float      # [N s/m]
    c1b: float      # [N s/(m V)]
    k1: float       # [N/m]
    x0: float       # [m] accumulator initial displacement
    alpha_a: float  # [N/m]
    alpha_b: float  # [N/(m V)]
    gamma: float    # [1/m^2]
    beta: float     # [1/m^2]
    A: float        # [-]
    n: float        # [-]
    eta: float      # [1/s] voltage filter (settled at constant voltage)

    def at(self, voltage):
        """Return ``(alpha, c0, c1)`` at a constant command ``voltage`` [V]."""
        u = float(voltage)
        return (self.alpha_a + self.alpha_b * u, self.c0a + self.c0b * u,
                self.c1a + self.c1b * u)

    def as_dict(self):
        """Return the parameters as a plain dict (JSON)."""
        return asdict(self)


#: Spencer et al. (1997), identified parameters of their prototype damper (the paper gives
#: them in N, cm, s, V: c0a 21.0 N s/cm, c0b 3.50 N s/(cm V), k0 46.9 N/cm, c1a 283 N s/cm,
#: c1b 2.95 N s/(cm V), k1 5.00 N/cm, x0 14.3 cm, alpha_a 140 N/cm, alpha_b 695 N/(cm V),
#: gamma = beta = 363 cm^-2, A 301, n 2, eta 190 s^-1).
SPENCER_1997 = MRParameters(c0a=2100.0, c0b=350.0, k0=4690.0, c1a=28300.0, c1b=295.0,
                            k1=500.0, x0=0.143, alpha_a=14000.0, alpha_b=69500.0,
                            gamma=3.63e6, beta=3.63e6, A=301.0, n=2.0, eta=190.0)
#: The voltage range of the paper's tests [V].
SPENCER_VOLTAGE_RANGE = (0.0, 2.25)


def check_voltage(voltage):
    """Return ``voltage`` as float, or raise ValueError naming the parameter."""
    v = float(voltage)
    if not (math.isfinite(v) and v >= 0):
        raise ValueError(f'parameter mr_voltage_v = {voltage!r} must be a finite voltage >= 0 '
                         f'(Spencer et al. 1997 tested {SPENCER_VOLTAGE_RANGE[0]}-'
                         f'{SPENCER_VOLTAGE_RANGE[1]} V)')
    return v


class MRDamper:
    """Internal states ``(z, y)`` of the model at a constant voltage; see the module doc."""

    def __init__(self, params: MRParameters = SPENCER_1997, voltage=0.0):
        """Store the parameters at ``voltage`` [V] and start at rest."""
        self.params = params
        self.voltage = check_voltage(voltage)
        self._alpha, self._c0, self._c1 = params.at(self.voltage)
        self.reset()

    def reset(self):
        """Return to rest: ``z = 0``, ``y = 0``, zero stroke."""
        self.z = 0.0
        self.y = 0.0
        self.x = 0.0
        self.ydot = 0.0

    def _rates(self, x, xd, z, y):
        p = self.params
        ydot = (self._alpha * z + self._c0 * xd + p.k0 * (x - y)) / (self._c0 + self._c1)
        rel = xd - ydot
        az = abs(z)
        zn = az ** p.n if p.n != 2.0 else az * az
        zn1 = az ** (p.n - 1.0) if p.n != 2.0 else az
        zdot = -p.gamma * abs(rel) * z * zn1 - p.beta * rel * zn + p.A * rel
        return zdot, ydot

    def advance(self, x0, v0, x1, v1, h):
        """Advance the states by ``h`` [s] (one RK4 step); stroke and velocity linear in it."""
        z, y = self.z, self.y
        xm, vm = 0.5 * (x0 + x1), 0.5 * (v0 + v1)
        k1z, k1y = self._rates(x0, v0, z, y)
        k2z, k2y = self._rates(xm, vm, z + 0.5 * h * k1z, y + 0.5 * h * k1y)
        k3z, k3y = self._rates(xm, vm, z + 0.5 * h * k2z, y + 0.5 * h * k2y)
        k4z, k4y = self._rates(x1, v1, z + h * k3z, y + h * k3y)
        self.z = z + h / 6.0 * (k1z + 2 * k2z + 2 * k3z + k4z)
        self.y = y + h / 6.0 * (k1y + 2 * k2y + 2 * k3y + k4y)
        self.x = x1
        self.ydot = self._rates(x1, v1, self.z, self.y)[1]

    def force(self):
        """Return the damper force [N] at the current state (tared: zero at rest)."""
        return self._c1 * self.ydot + self.params.k1 * self.x


class MRSpecimen(StrokeSpecimen):
    """The MR damper on a perfect actuator: stroke [m] in, force [N] out, one loop step each.

    The velocity at step k is ``(3 x_k - 4 x_{k-1} + x_{k-2}) / (2 dt)``; the
    states are integrated over ``substeps`` RK4 steps per loop step.
    """

    def __init__(self, dt, voltage=0.0, params: MRParameters = SPENCER_1997, substeps=8):
        """Set the loop step [s], the constant voltage [V], the model and its sub-steps."""
        super().__init__(MRDamper(params, voltage), dt, substeps)
        self.damper = self.device


def simulate_mr_reference(numerical_params, voltage, params: MRParameters = SPENCER_1997):
    """Whole-numerical RTHS reference: the building with the MR damper on a perfect actuator.

    ``numerical_params`` are those of the run's numerical substructure (same
    model, record, integrator, force scale, interface frame).  Returns the
    substructure's history (``output_disp`` is the reference 2nd-floor response).
    """
    sub = make_substructure(numerical_params)
    return coupled_rths(sub, MRSpecimen(sub.dt, voltage, params))
