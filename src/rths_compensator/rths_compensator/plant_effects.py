"""Fold the effects of an updated actuator model into its ARX plant.

``rths discrepancy --scenario actuator`` writes ``updated_model.yaml``: the ARX
plant it was given (``kind: arx``) plus ``effects: {NAME: VALUE}`` in the
conventions of ``rths_discrepancy.effects`` (actuator table).  The compensator
designs on an :class:`ArxModel` only, so the effects that are linear in the
plant's output are folded into its coefficients here; any other effect is
refused with a message (never dropped).

Folded (``y`` measured, ``u`` command, ``fs`` the plant's rate)::

    time_delay             tau [s]   y(t - tau): dead time d += floor(tau fs), the fraction
                                     f by linear interpolation, b <- conv(b, [1 - f, f])
    stiffness_error        kappa [-]  q = kappa y
    viscous_damping_error  tau_v [s]  q = tau_v yd
    mass_error             mu [s^2]   q = mu ydd

The loop load ``q`` enters as ``y = T (u - q)``; ``q_k``, held with ``u_k`` over sample
k, is the load at the middle of that sample (as the discrepancy simulator evaluates it,
``rths_discrepancy.models``): ``q = Q(z) y`` with the centred displacement
``(1 + z^-1) / 2``, velocity ``fs (1 - z^-1)`` and acceleration extrapolated to the
middle, ``fs^2 (1 - z^-1)^2 (1.5 - 0.5 z^-1)``::

    Q = kappa (1 + z^-1) / 2 + tau_v fs (1 - z^-1) + mu fs^2 (1 - z^-1)^2 (1.5 - 0.5 z^-1)

so the folded denominator is ``A + z^-d B Q`` (normalised to a leading 1, the
numerator with it).

The non-linear loads on the servo loop, ``coulomb_friction`` and ``cubic_stiffness``
(:data:`LOADS`), cannot be folded: :func:`split_effects` hands them to the compensator's
load feed-forward (:mod:`.feedforward`), which ``rths design`` writes.
"""

import math

import numpy as np

#: Effects :func:`fold_effects` can fold into an ARX plant.
FOLDABLE = ('time_delay', 'stiffness_error', 'viscous_damping_error', 'mass_error')
#: Non-linear loads of the servo loop the compensator applies as a feed-forward.
LOADS = ('coulomb_friction', 'cubic_stiffness')

_WHY = {
    'coulomb_friction': 'friction is non-linear; a linear compensator cannot hold it',
    'cubic_stiffness': 'a cubic load is non-linear; a linear compensator cannot hold it',
    'backlash': 'play is non-linear, and the library puts it between the rod and the '
                'displacement sensor: the table follows the command, only the reading '
                'lags; a compensator that inverted it would move the table off its target',
    'velocity_saturation': 'a rate limit is non-linear; a linear compensator cannot hold it',
    'sensor_bias': 'a constant offset does not change the dynamics the compensator inverts; '
                   'zero the displacement sensor instead',
    'force_offset': 'the actuator plant has no force channel',
}


def fold_effects(a, b, d, fs_hz, effects, where='plant'):
    """Return ``(a, b, d)`` of the ARX plant with ``effects`` folded in.

    ValueError names the file (``where``), the effect and why, for an effect
    that cannot be folded or a non-finite / negative value.
    """
    a = np.asarray(a, dtype=float).ravel()
    b = np.asarray(b, dtype=float).ravel()
    d = int(d)
    if not isinstance(effects, dict):
        raise ValueError(f'{where}: effects must be a mapping NAME: VALUE')
    values = {}
    for name, value in effects.items():
        if name not in FOLDABLE:
            why = _WHY.get(name, 'it is not an effect of the actuator library')
            raise ValueError(f'{where}: effect {name!r} cannot be used for the compensator '
                             f'design ({why}); remove it from effects or use a model '
                             f'with only {", ".join(FOLDABLE)}')
        try:
            values[name] = float(value)
        except (TypeError, ValueError):
            raise ValueError(f'{where}: effect {name!r} = {value!r} is not a number') from None
        if not math.isfinite(values[name]):
            raise ValueError(f'{where}: effect {name!r} = {value!r} is not finite')
    a, b, d = _fold_loop(a, b, d, fs_hz, values)
    tau = values.get('time_delay', 0.0)
    if tau < 0:
        raise ValueError(f'{where}: effect time_delay = {tau} s is negative; a plant cannot '
                         'answer before its command')
    if tau:
        shift = tau * fs_hz
        whole = int(math.floor(shift + 1e-9))
        frac = shift - whole
        d += whole
        if frac > 1e-3:
            b = np.convolve(b, [1.0 - frac, frac])
    return a, b, d


def split_effects(effects, where='plant'):
    """Return ``(foldable, loads)``: the effects :func:`fold_effects` folds, the feed-forward's.

    ValueError names the file, the effect and why for any other effect (never dropped).
    """
    if not isinstance(effects, dict):
        raise ValueError(f'{where}: effects must be a mapping NAME: VALUE')
    loads = {}
    for name, value in effects.items():
        if name in LOADS:
            try:
                loads[name] = float(value)
            except (TypeError, ValueError):
                raise ValueError(f'{where}: effect {name!r} = {value!r} is not a '
                                 'number') from None
            if not math.isfinite(loads[name]):
                raise ValueError(f'{where}: effect {name!r} = {value!r} is not finite')
        elif name not in FOLDABLE:
            why = _WHY.get(name, 'it is not an effect of the actuator library')
            raise ValueError(f'{where}: effect {name!r} cannot be used for the compensator '
                             f'design ({why}); remove it from effects or use a model '
                             f'with only {", ".join(FOLDABLE + LOADS)}')
    if loads.get('coulomb_friction', 0.0) < 0:
        raise ValueError(f"{where}: effect 'coulomb_friction' = {loads['coulomb_friction']} "
                         'is negative; a Coulomb load opposes the motion (d_c >= 0)')
    return {k: v for k, v in effects.items() if k not in LOADS}, loads


def _fold_loop(a, b, d, fs, values):
    """Denominator ``A + z^-d B Q`` of the linear loop loads (module doc)."""
    kappa = values.get('stiffness_error', 0.0)
    tau_v = values.get('viscous_damping_error', 0.0)
    mu = values.get('mass_error', 0.0)
    if not (kappa or tau_v or mu):
        return a, b, d
    diff = np.array([1.0, -1.0])
    q = np.zeros(4)
    q[:2] += kappa * np.array([0.5, 0.5])
    q[:2] += tau_v * fs * diff
    q[:4] += mu * fs * fs * np.convolve(np.convolve(diff, diff), [1.5, -0.5])
    bq = np.concatenate([np.zeros(d), np.convolve(b, q)])
    size = max(a.size, bq.size)
    new_a = np.zeros(size)
    new_a[:a.size] += a
    new_a[:bq.size] += bq
    lead = new_a[0]
    if not (math.isfinite(lead) and lead > 0):
        raise ValueError(f'the loads kappa={kappa}, tau_v={tau_v}, mu={mu} make the folded '
                         'plant improper (its leading coefficient is not > 0)')
    return np.trim_zeros(new_a, 'b') / lead, b / lead, d
