"""Load feed-forward: the identified non-linear loads of the servo loop added to the command.

``rths discrepancy --scenario actuator`` names loads on the actuator's servo loop in the
conventions of ``rths_discrepancy.effects`` (actuator table)::

    y = T (u - q),   q = d_c tanh(yd / v_eps) + k3 y^3        (coulomb_friction, cubic_stiffness)

with ``q_k``, held with ``u_k`` over sample k, the load at the middle of that sample
(displacement ``(y_k + y_{k-1}) / 2``, velocity ``(y_k - y_{k-1}) fs``; the simulator
``rths_discrepancy.models``).  A linear compensator ``G`` cannot hold such a load (it
would be refused as a plant effect); its inverse is exact in the form of a feed-forward:
the designed filter makes ``T G = 1`` over the band, so the command

    u_k = (G x)_k + q(x_k-mid),   x_k-mid = (x_k + x_{k-1}) / 2,  v = (x_k - x_{k-1}) fs

(the load evaluated on the desired trajectory ``x``, the interface displacement the
compensator receives) gives ``y = T G x + T (q(x) - q(y)) = x`` wherever ``y`` follows ``x``.
The linear loads (stiffness, velocity, inertia) are folded into the plant the filter is
designed on instead (:mod:`.plant_effects`).

Parameters (compensator file, written by ``rths design --plant updated_model.yaml``;
:data:`FEEDFORWARD_PARAMS`): ``feedforward_coulomb_friction_m`` (d_c [m]),
``feedforward_cubic_stiffness_1_m2`` (k3 [1/m^2]) and ``feedforward_v_eps_m_s`` (the
velocity scale of the sign law, the library's 1 mm/s).  All zero: no feed-forward.  Every
channel gets the same law (one actuator model).
"""

import math

import numpy as np

#: Velocity scale [m/s] of the regularised Coulomb law tanh(v / v_eps): the discrepancy
#: library's (``rths_discrepancy.effects.V_EPS``), which identified d_c with it.
V_EPS_M_S = 1e-3

#: Compensator keys of the feed-forward: key -> (default, meaning [unit]).
FEEDFORWARD_PARAMS = {
    'feedforward_coulomb_friction_m': (
        0.0, '[m] load feed-forward: the Coulomb load d_c tanh(v / feedforward_v_eps_m_s) on '
             'the servo loop (coulomb_friction of an updated actuator model), evaluated on the '
             'desired trajectory and added to the command; 0 = off'),
    'feedforward_cubic_stiffness_1_m2': (
        0.0, '[1/m^2] load feed-forward: the cubic load k3 x^3 on the servo loop '
             '(cubic_stiffness of an updated actuator model); 0 = off'),
    'feedforward_v_eps_m_s': (
        V_EPS_M_S, "[m/s] velocity scale of the feed-forward's Coulomb sign law (the "
                   "discrepancy library's 1 mm/s)"),
}

#: The actuator effects the feed-forward applies -> its key.
LOAD_KEYS = {'coulomb_friction': 'feedforward_coulomb_friction_m',
             'cubic_stiffness': 'feedforward_cubic_stiffness_1_m2'}


def feedforward_settings(params: dict, where: str = 'compensator parameters') -> dict:
    """Return the feed-forward's values from compensator ``params`` (defaults for the absent).

    ValueError names the key and the fix for a value that is not a finite number, a negative
    Coulomb load or a velocity scale that is not > 0.
    """
    out = {}
    for key, (default, meaning) in FEEDFORWARD_PARAMS.items():
        raw = params.get(key, default)
        try:
            val = float(raw)
        except (TypeError, ValueError):
            raise ValueError(f'{where}: {key} = {raw!r} is not a number; set it to '
                             f'{meaning}') from None
        if not math.isfinite(val):
            raise ValueError(f'{where}: {key} = {raw!r} is not finite; set it to {meaning}')
        out[key] = val
    if out['feedforward_coulomb_friction_m'] < 0:
        raise ValueError(f"{where}: feedforward_coulomb_friction_m = "
                         f"{out['feedforward_coulomb_friction_m']} is negative; a Coulomb load "
                         'opposes the motion: give d_c >= 0')
    if not out['feedforward_v_eps_m_s'] > 0:
        raise ValueError(f"{where}: feedforward_v_eps_m_s = {out['feedforward_v_eps_m_s']} "
                         'must be > 0 (the library identifies d_c with 1e-3 m/s)')
    return out


def feedforward_params(loads: dict) -> dict:
    """Return the compensator keys of the loads ``{effect: value}`` of an updated model."""
    unknown = sorted(set(loads) - set(LOAD_KEYS))
    if unknown:
        raise ValueError(f'load feed-forward: {", ".join(unknown)} is not a load it applies; '
                         f'use {", ".join(LOAD_KEYS)}')
    return {LOAD_KEYS[name]: float(value) for name, value in loads.items()}


class LoadFeedForward:
    """The feed-forward of one or more channels: ``step(x)`` -> the load to add to the command.

    ``fs_hz`` is the loop rate; the state is the previous desired displacement per channel
    (zero before the first step: the run starts at rest).
    """

    def __init__(self, settings: dict, fs_hz: float):
        self.d_c = float(settings['feedforward_coulomb_friction_m'])
        self.k3 = float(settings['feedforward_cubic_stiffness_1_m2'])
        self.v_eps = float(settings['feedforward_v_eps_m_s'])
        self.fs = float(fs_hz)
        self.prev = None

    @property
    def active(self) -> bool:
        """Return True if any load is non-zero."""
        return bool(self.d_c or self.k3)

    def step(self, x) -> np.ndarray:
        """Return ``q`` [m] per channel at the middle of this step for the desired ``x`` [m]."""
        x = np.asarray(x, dtype=float)
        prev = np.zeros_like(x) if self.prev is None or self.prev.shape != x.shape else self.prev
        self.prev = x.copy()
        mid = 0.5 * (x + prev)
        q = self.k3 * mid ** 3
        if self.d_c:
            q = q + self.d_c * np.tanh((x - prev) * (self.fs / self.v_eps))
        return q


def from_params(params: dict, where: str = 'compensator parameters'):
    """Return the :class:`LoadFeedForward` of compensator ``params``, or None when it is off."""
    ff = LoadFeedForward(feedforward_settings(params, where), float(params.get('fs_hz', 1024.0)))
    return ff if ff.active else None
