"""A device specimen of the simulated plant: between the table and the ground, driven by its stroke.

The device (a specimen entry's ``device`` in :mod:`rths_numerical.specimens`, e.g.
the MR damper of Spencer et al. 1997, :class:`rths_numerical.mr_damper.MRDamper`)
sits between the shake table and the reaction frame: its stroke is the table
displacement ``x_s``.  Each sample is split into ``substeps`` exact-ZOH
sub-steps of the actuator; at every sub-step end the table displacement and
velocity (actuator states, no differentiation) advance the device's states
(``advance(x0, v0, x1, v1, h)``).  The measured force is the device force (plus
``frame_mass_kg`` times the table acceleration, 0 by default: the load cell
sits at the device's rod).  The device does not load the actuator (as for the
DTM: the actuator model is command -> displacement).
"""

import numpy as np

from .channels import CHANNELS, zoh


class StrokeTableSpecimen:
    """Advances a :class:`~.simulated.SimulatedPlant` (bare table) with a device on it."""

    def __init__(self, plant, device, substeps: int, name: str):
        """Check the plant (continuous actuator) and precompute the sub-step matrices."""
        if plant.arx is not None:
            raise ValueError(f"parameter 'specimen' = {name!r} needs a continuous actuator "
                             "model ('3pole' or '4pole'), not an ARX plant.yaml")
        if substeps < 1:
            raise ValueError(f'specimen {name!r}: sub-steps = {substeps} must be >= 1')
        self.plant = plant
        self.damper = device
        self.h = plant.dt / substeps
        self.substeps = substeps
        self._ad, bd = zoh(plant.a_c, plant.b_c, self.h)
        self._bd_u = np.ascontiguousarray(bd[:, 0])
        self._c_disp = plant.c[CHANNELS.index('table_disp')].copy()
        self._c_vel = plant.c[CHANNELS.index('table_vel')].copy()
        self._i_force = CHANNELS.index('force')
        self._i_accel = CHANNELS.index('table_accel')
        self._channels = CHANNELS

    def reset(self):
        """Put the damper at rest (the plant resets its own states)."""
        self.damper.reset()

    def step(self, u):
        """Hold command ``u`` [m] for one sample; return the plant's true channels."""
        plant = self.plant
        x = plant.x
        xs0, vs0 = float(self._c_disp @ x), float(self._c_vel @ x)
        for _ in range(self.substeps):
            x = self._ad @ x + self._bd_u * u
            xs1, vs1 = float(self._c_disp @ x), float(self._c_vel @ x)
            self.damper.advance(xs0, vs0, xs1, vs1, self.h)
            xs0, vs0 = xs1, vs1
        plant.x = x
        y = plant.c @ x + plant.d[:, 0] * u
        y[self._i_force] = plant.frame_mass * y[self._i_accel] + self.damper.force()
        plant.k += 1
        plant.true = dict(zip(self._channels, y.tolist(), strict=True))
        return plant.true
