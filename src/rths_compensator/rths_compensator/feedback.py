"""The RTHS benchmark's reference controller: PI tracking control with a phase lead.

Silva et al. (2020, MSSP 135, 106381, eq. 23-24): the command is

    u = G_C (G_T y - x_m),   G_T(s) = (50.8316 s + 8570.4) / (s + 8570.4),
                             G_C(s) = K_p + K_i / s,  K_p = 2, K_i = 95 s^-1

(the gains and the lead are the compensator parameters ``pi_lead_kp``, ``pi_lead_ki``,
``pi_lead_num``, ``pi_lead_den``, these values by default), with y the target (interface)
displacement and x_m the measured displacement, both
discretised by Tustin at the loop's rate.  In the node graph x_m is the measured
displacement of step k-1 (the bridge measures it at the end of that step's sample, the
instant the benchmark's controller samples it).

Guards (the adaptive methods' :class:`~rths_compensator.adaptive.Guards`, through
:class:`~rths_compensator.adaptive.AdaptiveMethod`): a non-finite target, measurement or
command, or a relative RMS tracking error above ``fallback_pct`` while excited, switches
to the designed filter of the compensator parameters for the rest of the run (bumpless:
it runs in parallel); while the bridge changes the commands (a hold, a ramp or a limit:
:meth:`flag_fault`) the integrator is frozen, so it does not wind up against the hold.
A lost measurement holds the last one.
"""

import numpy as np
from scipy import signal

from .adaptive import AdaptiveMethod, Status
from .design import Design

#: The paper's gains and lead (eq. 23-24).
KP, KI = 2.0, 95.0
LEAD = ((50.8316, 8570.40), (1.0, 8570.40))


class PiLead(AdaptiveMethod):
    """``u = G_C (G_T target - measured)`` (see module doc), Tustin at the design's rate."""

    name = 'pi_lead'

    @classmethod
    def options_from_params(cls, params: dict) -> dict:
        """Return the options of compensator parameters (``pi_lead_*``, paper defaults)."""
        return {'kp': float(params.get('pi_lead_kp', KP)),
                'ki': float(params.get('pi_lead_ki', KI)),
                'lead_num': tuple(params.get('pi_lead_num', LEAD[0])),
                'lead_den': tuple(params.get('pi_lead_den', LEAD[1]))}

    def __init__(self, design: Design, guards=None, kp=KP, ki=KI, lead_num=LEAD[0],
                 lead_den=LEAD[1]):
        super().__init__(design, guards)
        if not (np.isfinite(kp) and np.isfinite(ki) and ki >= 0.0):
            raise ValueError(f'pi_lead gains pi_lead_kp {kp}, pi_lead_ki {ki}: give finite '
                             'values, pi_lead_ki >= 0')
        num, den = signal.bilinear(np.asarray(lead_num, float), np.asarray(lead_den, float),
                                   self.fs_hz)
        if num.size != 2 or den.size != 2:
            raise ValueError('pi_lead_num/pi_lead_den: a first-order lead '
                             '(b1 s + b0) / (a1 s + a0) is expected')
        self.lead = (float(num[0] / den[0]), float(num[1] / den[0]), float(den[1] / den[0]))
        self.kp, self.ki = float(kp), float(ki)
        self._half_ki_dt = 0.5 * self.ki * self.dt
        self._lead_x = 0.0          # previous target
        self._lead_y = 0.0          # previous lead output
        self._integral = 0.0
        self._error = 0.0           # previous error
        self._measured = 0.0
        self.status = Status('fixed', 'PI + lead: no measurement yet')

    @classmethod
    def from_design(cls, design: Design, plant=None, guards=None, **options):
        """Build the controller; ``design`` is its fallback (the plant is not used)."""
        return cls(design, guards, **options)

    def _command(self, target):
        n0, n1, d1 = self.lead
        desired = n0 * target + n1 * self._lead_x - d1 * self._lead_y
        self._lead_x, self._lead_y = target, desired
        error = desired - self._measured
        if not self._fault:     # Tustin integrator, frozen while the bridge holds/limits
            self._integral += self._half_ki_dt * (error + self._error)
        self._error = error
        return self.kp * error + self._integral

    def _record(self, measured, adapt):
        self._measured = measured
        if self._state != 'fallback' and not self._fault:
            self._state, self._reason = 'fixed', 'PI + lead on the measured displacement'
        return False          # kp, ki fixed; a non-finite integral makes the command so

    def coefficients(self):
        """Return ``[kp, ki, integral state (m)]``."""
        return np.array([self.kp, self.ki, self._integral])
