"""Library of candidate physical effects the discrepancy workflow can name.

Every effect is a physical term with named SI parameters.  It acts either in
the model's *loop* (a term ``q`` added to the model's input, evaluated on the
states) or on the model's *output* (an operator applied to the simulated
output, e.g. a delay).

Specimen (the DTM on the shake table, seed eq. 46)::

    m_d xdd + c_d xd + k_d x + f(x, xd) = -(m_d + dm) xdd_s - dm xdd       (46 + effect)

i.e. ``m_d xdd + c_d xd + k_d x = -m_d (xdd_s + q)`` with ``q = f / m_d``
(plus ``q = dm (xdd + xdd_s) / m_d`` for a mass error), so the nominal
transfer function of eq. 47, ``T_DTM = -m_d / (m_d s^2 + c_d s + k_d)``, maps
``xdd_s + q`` to ``x_d2s``.  Effect forces ``f`` [N]:

=====================  =========================================  ==========
effect                 term                                       parameters
=====================  =========================================  ==========
coulomb_friction       F_c tanh(xd / v_eps), v_eps = 1 mm/s       F_c [N]
viscous_damping_error  dc xd                                      dc [N s/m]
stiffness_error        dk x                                       dk [N/m]
cubic_stiffness        k3 x^3                                     k3 [N/m^3]
mass_error             dm (xdd + xdd_s)  (inertia, see above)     dm [kg]
backlash               k_d (dz(x, b) - x), clearance +-b          b [m]
velocity_saturation    c_d (clip(xd, -v_sat, v_sat) - xd)         v_sat [m/s]
time_delay             outputs read tau late: y(t - tau)          tau [s]
sensor_bias            rel_disp offset: x_meas = x + bias         bias [m]
force_offset           load-cell offset: R_read = R + F_0         F_0 [N]
=====================  =========================================  ==========

``dz(x, b) = sign(x) max(|x| - b, 0)`` (the spring engages after a clearance).

``force_offset`` is an offset of the load-cell *reading* ``R`` (the force the load cells
under the frame measure, the force a bridge returns to the numerical substructure, the
simulated lab's ``force_offset_n``): ``R_read = R + F_0``, one convention for every
scenario.  The specimen scenario's ``force`` channel is eq. 45's force the damper exerts
on its frame, derived from that reading as ``F = m_f xdd_s - R`` (the load cells also
carry the frame's inertia; :func:`rths_common.bagio.read_specimen`), so a reading offset
``+F_0`` shows in it as ``-F_0``: ``F_read = F - F_0``.

Actuator (Table 1 model or ARX, seed eq. 3 / 26): ``y = G(s) (u - q)``, where
``q`` is the displacement-equivalent load that the specimen and the rod put on
the servo loop (control-structure interaction), or an operator on the output:

=====================  =========================================  ==========
coulomb_friction       d_c tanh(yd / v_eps)                       d_c [m]
viscous_damping_error  tau_v yd                                   tau_v [s]
stiffness_error        kappa y                                    kappa [-]
cubic_stiffness        k3 y^3                                     k3 [1/m^2]
mass_error             mu ydd                                     mu [s^2]
backlash               play operator of half-width b on y         b [m]
velocity_saturation    rate limit |yd| <= v_max on y              v_max [m/s]
time_delay             y(t - tau)                                 tau [s]
sensor_bias            y + bias                                   bias [m]
=====================  =========================================  ==========

(``force_offset`` is a specimen effect only: the actuator record has no force.)
"""

from dataclasses import dataclass
import math

import numpy as np

#: Velocity scale of the regularised Coulomb law tanh(v / V_EPS) [m/s].
V_EPS = 1e-3

#: Candidate names, in the order used for combinations ('a+b').
EFFECT_NAMES = (
    'coulomb_friction', 'viscous_damping_error', 'stiffness_error', 'cubic_stiffness',
    'mass_error', 'backlash', 'time_delay', 'velocity_saturation', 'sensor_bias',
    'force_offset',
)

SCENARIOS = ('specimen', 'actuator')


@dataclass(frozen=True)
class Effect:
    """One candidate effect of one scenario.

    ``kind`` is 'loop' (term added to the model input, built from states) or
    'output' (operator on the simulated output).  ``linear`` means the effect
    is ``param * regressor`` (loop) or ``+ param`` (bias), so it can be fitted
    by linear least squares; otherwise its single parameter is found by a 1-D
    search in ``bounds`` (relative to ``scale`` when ``relative`` is set).
    """

    name: str
    param: str
    unit: str
    kind: str
    linear: bool
    description: str


_SPECIMEN = {
    'coulomb_friction': Effect('coulomb_friction', 'F_c', 'N', 'loop', True,
                               'Coulomb friction F_c tanh(v/v_eps) on the moving mass'),
    'viscous_damping_error': Effect('viscous_damping_error', 'dc', 'N s/m', 'loop', True,
                                    'missing viscous damping dc v'),
    'stiffness_error': Effect('stiffness_error', 'dk', 'N/m', 'loop', True,
                              'stiffness error dk x'),
    'cubic_stiffness': Effect('cubic_stiffness', 'k3', 'N/m^3', 'loop', True,
                              'hardening/softening spring k3 x^3'),
    'mass_error': Effect('mass_error', 'dm', 'kg', 'loop', True,
                         'moving-mass error dm (inertia and base-excitation load)'),
    'backlash': Effect('backlash', 'b', 'm', 'loop', False,
                       'clearance +-b before the spring engages'),
    'time_delay': Effect('time_delay', 'tau', 's', 'output', False,
                         'measured outputs lag the input by tau'),
    'velocity_saturation': Effect('velocity_saturation', 'v_sat', 'm/s', 'loop', False,
                                  'damping force saturates above |v| = v_sat (choked valve)'),
    'sensor_bias': Effect('sensor_bias', 'bias', 'm', 'output', True,
                          'constant offset of the displacement sensor'),
    'force_offset': Effect('force_offset', 'F_0', 'N', 'output', True,
                           'constant offset (bias) of the load-cell reading R + F_0 (eq. 45 '
                           'force, derived m_f xdd_s - R: F - F_0)'),
}

_ACTUATOR = {
    'coulomb_friction': Effect('coulomb_friction', 'd_c', 'm', 'loop', True,
                               'Coulomb friction, displacement-equivalent d_c tanh(v/v_eps)'),
    'viscous_damping_error': Effect('viscous_damping_error', 'tau_v', 's', 'loop', True,
                                    'velocity load on the servo loop tau_v v'),
    'stiffness_error': Effect('stiffness_error', 'kappa', '-', 'loop', True,
                              'stiffness load (gain error) kappa y'),
    'cubic_stiffness': Effect('cubic_stiffness', 'k3', '1/m^2', 'loop', True,
                              'cubic stiffness load k3 y^3'),
    'mass_error': Effect('mass_error', 'mu', 's^2', 'loop', True,
                         'inertia load mu a'),
    'backlash': Effect('backlash', 'b', 'm', 'output', False,
                       'mechanical play of half-width b between rod and sensor'),
    'time_delay': Effect('time_delay', 'tau', 's', 'output', False,
                         'extra pure delay tau'),
    'velocity_saturation': Effect('velocity_saturation', 'v_max', 'm/s', 'output', False,
                                  'servo-valve flow limit |v| <= v_max'),
    'sensor_bias': Effect('sensor_bias', 'bias', 'm', 'output', True,
                          'constant offset of the displacement sensor'),
}

LIBRARY = {'specimen': _SPECIMEN, 'actuator': _ACTUATOR}


def effect(scenario: str, name: str) -> Effect:
    """Return the :class:`Effect` ``name`` of ``scenario`` (ValueError names the choices)."""
    if scenario not in LIBRARY:
        raise ValueError(f'unknown scenario {scenario!r}; use one of {", ".join(SCENARIOS)}')
    try:
        return LIBRARY[scenario][name]
    except KeyError:
        raise ValueError(f'unknown effect {name!r} for {scenario}; use one of '
                         f'{", ".join(LIBRARY[scenario])}') from None


def nonlinear_bounds(scenario: str, name: str, scales: dict) -> tuple:
    """Search interval of the parameter of a non-linear effect, from signal ``scales``.

    ``scales`` holds 'y_rms' (output rms), 'v_rms' and 'v_max' (velocity rms
    and peak).  Delays are searched in [-20 ms, 50 ms].
    """
    if name == 'time_delay':
        return (-0.02, 0.05)
    if name == 'backlash':
        return (1e-3 * scales['y_rms'], 0.6 * scales['y_rms'])
    if name == 'velocity_saturation':
        return (0.05 * scales['v_max'], 1.0 * scales['v_max'])
    raise ValueError(f'{name} is not a non-linear effect of {scenario}')


def deadzone(x, b):
    """Return ``sign(x) max(|x| - b, 0)``: the clearance (backlash) spring law."""
    return np.sign(x) * np.maximum(np.abs(x) - b, 0.0)


def _play_loop(y, b, out):
    z = y[0]
    for k in range(y.size):
        lo = y[k] - b
        hi = y[k] + b
        if z < lo:
            z = lo
        elif z > hi:
            z = hi
        out[k] = z
    return out


def _rate_loop(y, step, out):
    z = y[0]
    for k in range(y.size):
        d = y[k] - z
        if d > step:
            d = step
        elif d < -step:
            d = -step
        z += d
        out[k] = z
    return out


def _bouc_wen_loop(x, x_y, out):
    z = 0.0
    out[0] = 0.0
    for k in range(1, x.size):
        dx = x[k] - x[k - 1]
        if dx != 0.0:
            s = 1.0 if dx > 0 else -1.0
            step = abs(dx) / x_y
            if z * s < 0.0:            # unloading: dz = dx / x_y until z crosses 0
                lin = min(step, abs(z))
                z += s * lin
                step -= lin
            if step > 0.0:             # loading: z -> s exponentially
                z = s - (s - z) * math.exp(-step)
        out[k] = z
    return out


_LOOPS = {}


def _loop(name):
    """Return the hysteretic loop ``name``, compiled by numba when it is installed (lazily)."""
    if not _LOOPS:
        loops = {'play': _play_loop, 'rate': _rate_loop, 'bouc_wen': _bouc_wen_loop}
        try:  # they run once per candidate evaluation: compiled they are ~100x faster
            # lazy: optional: tried here, refused with a clear message when missing
            import numba
            loops = {k: numba.njit(cache=True)(f) for k, f in loops.items()}
        except ImportError:  # pragma: no cover - plain Python
            pass
        _LOOPS.update(loops)
    return _LOOPS[name]


def play(y, b):
    """Play (backlash) operator of half-width ``b``: ``z_k = clip(z_{k-1}, y_k - b, y_k + b)``."""
    y = np.ascontiguousarray(y, dtype=float)
    return _loop('play')(y, float(b), np.empty_like(y))


def bouc_wen(x, x_y):
    """Bouc-Wen variable ``z`` (beta = gamma = 1/2, n = 1) of the path ``x``, exact per step.

    ``dz = dx / x_y (1 - |z| (1 + sign(dx z)) / 2)``: linear while unloading, an
    exponential approach to +-1 while loading; ``z`` stays within [-1, 1].
    """
    x = np.ascontiguousarray(x, dtype=float)
    return _loop('bouc_wen')(x, float(x_y), np.empty_like(x))


def rate_limit(y, v_max, dt):
    """Rate limiter: ``z_k = z_{k-1} + clip(y_k - z_{k-1}, -v_max dt, v_max dt)``."""
    y = np.ascontiguousarray(y, dtype=float)
    return _loop('rate')(y, float(v_max * dt), np.empty_like(y))


def delay(y, tau, fs):
    """Return ``y(t - tau)``, a band-limited (FFT, linear-phase) fractional delay.

    The record is padded with its first/last value beyond the delay (so the
    delayed signal holds the first value at the start), delayed in the
    frequency domain and cut back; an integer number of samples is an exact shift.
    """
    y = np.asarray(y, dtype=float)
    if tau == 0.0:
        return y.copy()
    n = y.size
    shift = tau * fs
    pad = int(math.ceil(abs(shift))) + 64
    ext = np.concatenate([np.full(pad, y[0]), y, np.full(pad, y[-1])])
    m = ext.size
    nfft = 1 << (m - 1).bit_length()
    ext = np.concatenate([ext, np.full(nfft - m, y[-1])])
    k = round(shift)
    if abs(shift - k) < 1e-9:
        return np.roll(ext, k)[pad:pad + n]
    spec = np.fft.rfft(ext)
    w = 2.0 * np.pi * np.fft.rfftfreq(nfft)
    spec *= np.exp(-1j * w * shift)
    if nfft % 2 == 0:
        spec[-1] = spec[-1].real * math.cos(np.pi * shift)
    return np.fft.irfft(spec, nfft)[pad:pad + n]


def loop_regressor(scenario: str, name: str, states: dict, nominal) -> np.ndarray:
    """Regressor ``phi`` of a linear loop effect: the loop term is ``param * phi``.

    ``states`` holds 'x' (output), 'v', 'a' (its derivatives) and 'u' (input);
    ``nominal`` gives m_d for the specimen (terms become accelerations, /m_d).
    """
    x, v = states['x'], states['v']
    if scenario == 'specimen':
        m = nominal.m_d
        table = {
            'coulomb_friction': lambda: np.tanh(v / V_EPS) / m,
            'viscous_damping_error': lambda: v / m,
            'stiffness_error': lambda: x / m,
            'cubic_stiffness': lambda: x ** 3 / m,
            'mass_error': lambda: (states['a'] + states['u']) / m,
        }
    else:
        table = {   # the sign law on the velocity band-limited for it (workflow.Context)
            'coulomb_friction': lambda: np.tanh(states.get('v_sign', v) / V_EPS),
            'viscous_damping_error': lambda: v,
            'stiffness_error': lambda: x,
            'cubic_stiffness': lambda: x ** 3,
            'mass_error': lambda: states['a'],
        }
    return table[name]()


def loop_term_nonlinear(name: str, p: float, states: dict, nominal) -> np.ndarray:
    """Loop term of a non-linear specimen effect (backlash, velocity_saturation), /m_d."""
    x, v = states['x'], states['v']
    if name == 'backlash':
        return nominal.k_d * (deadzone(x, p) - x) / nominal.m_d
    if name == 'velocity_saturation':
        return nominal.c_d * (np.clip(v, -p, p) - v) / nominal.m_d
    raise ValueError(f'{name} is not a non-linear loop effect')


def specimen_force(effects: dict, nominal):
    """Return ``f(x, v)`` [N] (scalar Python function) of the specimen loop effects.

    ``effects`` maps effect name to its parameter value; mass_error, time_delay
    and sensor_bias are not forces and are ignored here.
    """
    k_d, c_d = nominal.k_d, nominal.c_d
    fc = effects.get('coulomb_friction', 0.0)
    dc = effects.get('viscous_damping_error', 0.0)
    dk = effects.get('stiffness_error', 0.0)
    k3 = effects.get('cubic_stiffness', 0.0)
    b = effects.get('backlash')
    vs = effects.get('velocity_saturation')
    stribeck = effects.get('_stribeck')  # (F_c, F_s, v_s): data generation only

    def force(x, v):
        f = dc * v + dk * x + k3 * x * x * x
        if fc:
            f += fc * math.tanh(v / V_EPS)
        if b is not None:
            dz = math.copysign(max(abs(x) - b, 0.0), x)
            f += k_d * (dz - x)
        if vs is not None:
            f += c_d * (min(max(v, -vs), vs) - v)
        if stribeck is not None:
            f_c, f_s, v_s = stribeck
            f += (f_c + (f_s - f_c) * math.exp(-(v / v_s) ** 2)) * math.tanh(v / V_EPS)
        return f

    return force


def actuator_load(effects: dict):
    """Return ``q(y, v, a)`` [m] (scalar Python function) of the actuator loop effects."""
    dc = effects.get('coulomb_friction', 0.0)
    tv = effects.get('viscous_damping_error', 0.0)
    ka = effects.get('stiffness_error', 0.0)
    k3 = effects.get('cubic_stiffness', 0.0)
    mu = effects.get('mass_error', 0.0)
    stribeck = effects.get('_stribeck')

    def load(y, v, a):
        q = tv * v + ka * y + k3 * y * y * y + mu * a
        if dc:
            q += dc * math.tanh(v / V_EPS)
        if stribeck is not None:
            f_c, f_s, v_s = stribeck
            q += (f_c + (f_s - f_c) * math.exp(-(v / v_s) ** 2)) * math.tanh(v / V_EPS)
        return q

    return load


def apply_output_ops(scenario: str, y, effects: dict, fs: float, channel: str = 'x'):
    """Apply the output operators of ``effects`` to ``y``.

    Order: rate limit -> play -> delay -> bias (actuator); delay -> bias
    (specimen; the bias only on the displacement ``channel`` 'x').
    ``'_lag'`` (data generation only) is a first-order lag of time constant
    ``effects['_lag']`` [s], applied before the delay.
    """
    out = np.asarray(y, dtype=float)
    if scenario == 'actuator':
        if 'velocity_saturation' in effects:
            out = rate_limit(out, effects['velocity_saturation'], 1.0 / fs)
        if 'backlash' in effects:
            out = play(out, effects['backlash'])
    if '_lag' in effects:
        # lazy: start-up cost: SciPy (~1 s), which this module needs only here
        from scipy.signal import lfilter
        alpha = math.exp(-1.0 / (fs * effects['_lag']))
        out = lfilter([1.0 - alpha], [1.0, -alpha], out, zi=[alpha * out[0]])[0]
    if 'time_delay' in effects:
        out = delay(out, effects['time_delay'], fs)
    if 'sensor_bias' in effects and channel == 'x':
        out = out + effects['sensor_bias']
    if 'force_offset' in effects and channel == 'force':
        # eq. 45's force m_f xdd_s - R from a load-cell reading R + F_0 (module docstring)
        out = out - effects['force_offset']
    return out
