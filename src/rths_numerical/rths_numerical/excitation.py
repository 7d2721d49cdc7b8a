"""A prescribed interface displacement in place of the building: the identification run.

Before an RTHS the lab identifies the plant (actuator + table + specimen) by
driving it with band-limited white noise (seed section 4.3.1: BLWNs of 0~64 and
0~128 Hz, 2.54-38.1 mm peak; section 6.1 for the actuator with the DTM).
:class:`PrescribedExcitation` is a :class:`~.stepping.SteppedSubstructure` like
:class:`~rths_numerical.substructure.NumericalSubstructure`, so the numerical
node runs it unchanged (``model: excitation``): it ignores the measured force
and plays the signal, and its history keeps both for the identification.
"""

import math

import numpy as np

from rths_common.params import LOOP_RATE_RANGE_HZ, check_run_steps

from .signals import blwn
from .stepping import SteppedSubstructure

#: Parameters of ``model: excitation``: key -> (default, meaning [unit]).
EXCITATION_PARAMS = {
    'model': ('excitation', "'excitation': a prescribed BLWN interface displacement"),
    'fs_hz': (1024.0, '[Hz] loop rate'),
    'duration_s': (20.0, '[s] length of the excitation'),
    'excitation_band_hz': (64.0, '[Hz] BLWN band 0..f (seed 4.3.1: 0~64 Hz)'),
    'excitation_peak_m': (0.00254, '[m] peak displacement (seed 4.3.1: 0.1 in = 2.54 mm)'),
    'taper_s': (0.5, '[s] fade in/out so the actuator starts and ends at rest'),
    'seed': (0, '[-] random seed of the BLWN'),
}
#: Ranges of :data:`EXCITATION_PARAMS` (inclusive).
EXCITATION_RANGES = {
    'fs_hz': LOOP_RATE_RANGE_HZ,
    'duration_s': (0.0, 1.0e6),
    'excitation_band_hz': (0.0, 100_000.0),
    'excitation_peak_m': (0.0, 1.0),
    'taper_s': (0.0, 3600.0),
}
#: Default of every parameter of ``model: excitation``.
EXCITATION_DEFAULTS = {key: default for key, (default, _) in EXCITATION_PARAMS.items()}


class PrescribedExcitation(SteppedSubstructure):
    """Plays a prescribed interface displacement; records the measured force."""

    backend = 'builtin'

    def __init__(self, displacement, dt: float):
        """``displacement`` [m] per step (1-D: one interface DOF, or steps x DOFs)."""
        d = np.asarray(displacement, dtype=float)
        self._d = d.reshape(d.shape[0], -1)
        if not np.all(np.isfinite(self._d)):
            raise ValueError('the prescribed displacement holds nan/inf')
        self.dt = float(dt)
        self.n_steps, self.n_interface = self._d.shape
        self.reset()

    def reset(self):
        """Return to step 0 (the prescribed displacement is unchanged)."""
        self._force = np.zeros_like(self._d)
        self._k = 0

    def state(self) -> dict:
        """Return the step count, time [s] and interface displacement [m] of the last step."""
        k = self._k
        last = self._d[k - 1] if k else np.full(self.n_interface, np.nan)
        return {'step': k, 'time': (k - 1) * self.dt if k else float('nan'),
                'interface_disp': last.copy(), 'output_disp': float(last[0])}

    def first_displacement(self) -> np.ndarray:
        """Interface displacement command of step 0 [m]."""
        return self._d[0].copy()

    def advance(self, measured_force) -> np.ndarray:
        """Record the measured force of step k; return the displacement of step k+1."""
        self._force[self._k] = self.force_of(measured_force)
        self._k += 1
        return self._d[min(self._k, self.n_steps - 1)].copy()

    def done(self) -> bool:
        """Return True once every step has its measurement."""
        return self._k >= self.n_steps

    def history(self) -> dict:
        """Time, prescribed interface displacement and measured force of the finished steps."""
        k = self._k
        return {'time': np.arange(k) * self.dt, 'interface_disp': self._d[:k].copy(),
                'output_disp': self._d[:k, 0].copy(), 'command': self._d[:k].copy(),
                'measured_force': self._force[:k].copy()}


def make_excitation(params: dict) -> PrescribedExcitation:
    """Build the BLWN excitation of ``model: excitation`` from flat parameters."""
    unknown = set(params) - set(EXCITATION_DEFAULTS)
    if unknown:
        raise ValueError(f'unknown parameter(s) {", ".join(sorted(unknown))} for model '
                         f'excitation; known: {", ".join(EXCITATION_DEFAULTS)}')
    p = dict(EXCITATION_DEFAULTS, **params)
    for key in ('fs_hz', 'duration_s', 'excitation_band_hz', 'excitation_peak_m'):
        value = p[key]
        if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
            raise ValueError(f'parameter {key} = {value!r} must be a positive number')
    fs = float(p['fs_hz'])
    check_run_steps(p['duration_s'], fs)
    x = blwn(float(p['duration_s']), fs, float(p['excitation_band_hz']),
             float(p['excitation_peak_m']), rng=int(p['seed']), taper_s=float(p['taper_s']))
    return PrescribedExcitation(x, 1.0 / fs)
