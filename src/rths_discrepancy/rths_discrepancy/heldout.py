"""A second, independent simulator of the same physics: held-out records for the workflow.

The workflow is developed on :mod:`.selftest`'s records; these records come from a
different simulator, written separately, so that its conventions are not the
workflow's and nothing is tuned on them (the bench only counts how many are named):

* integrator: explicit midpoint (RK2) on 8 steps per sample, states in physical
  coordinates (specimen: x, xd; actuator: the controllable state space of the
  Table 1 3-pole model, its loads computed from the *state*, y' = C A x,
  y'' = C A^2 x, not from differences of the output);
* excitation: Gaussian noise through a 4th-order Butterworth low-pass
  (specimen 0-8 Hz, 0.6 m/s^2 rms; actuator 0-15 Hz, 3 mm rms), 0.5 s ramps;
* sampling: 1000 Hz (not 1024 Hz), 12 s records, noise 0.5 % of each
  channel's standard deviation;
* conventions: set A holds every input constant over the step (ZOH), reads the
  specimen at the end of the step and counts one more step of converter delay on
  the actuator; set B interpolates every input over the step, reads the specimen
  at the end and the actuator at the start of the step.

The effect laws are the physical ones of :mod:`.effects` (Coulomb with
``tanh(v / 0.5 mm/s)`` here, not 1 mm/s), with sizes chosen independently
(specimen response 4.4 mm rms, 15 mm peak; actuator 3.4 mm rms, 0.66 m/s peak).
Set A: 14 records of one effect or none; set B: 12 records, pairs included.
"""

import math
import time

import numpy as np
from scipy import signal

from rths_compensator.plants import continuous_actuator
from rths_discrepancy import effects as fx
from rths_discrepancy.jobs import run_with_progress
from rths_discrepancy.workflow import run_discrepancy

FS_HZ = 1000.0
DURATION_S = 12.0
NOISE = 0.005
SUB = 8
V_EPS = 5e-4

#: Specimen parameters: the Table 4 valve #4 damper (seed), typed in again.
M_D, C_D, K_D = 258.35, 491.6, 80810.0


def _excitation(rng, n, fs, band_hz, rms):
    sos = signal.butter(4, band_hz, fs=fs, output='sos')
    u = signal.sosfilt(sos, rng.standard_normal(n + 2000))[2000:]
    ramp = np.ones(n)
    k = int(0.5 * fs)
    ramp[:k] = np.linspace(0.0, 1.0, k)
    ramp[-k:] = np.linspace(1.0, 0.0, k)
    u = u * ramp
    return u * rms / np.std(u)


def _fine(u, interpolate, extra_step):
    if extra_step:
        u = np.concatenate([[u[0]], u[:-1]])
    if interpolate:
        return np.interp(np.arange(u.size * SUB) / SUB, np.arange(u.size), u)
    return np.repeat(u, SUB)


def _play(y, b):
    out = np.empty_like(y)
    z = y[0]
    for i, v in enumerate(y):
        z = min(max(z, v - b), v + b)
        out[i] = z
    return out


def _rate_limited(y, vmax, h):
    out = np.empty_like(y)
    z = y[0]
    for i, v in enumerate(y):
        z += min(max(v - z, -vmax * h), vmax * h)
        out[i] = z
    return out


def specimen_record(effects, seed, interpolate=False, output_start=False):
    """Specimen record (time, base_accel, rel_disp, force) with ``effects`` {name: value}."""
    rng = np.random.default_rng(1000 + seed)
    fs, n = FS_HZ, int(DURATION_S * FS_HZ)
    u = _excitation(rng, n, fs, 8.0, 0.6)
    uf = _fine(u, interpolate, False)
    m = M_D + effects.get('mass_error', 0.0)
    fc = effects.get('coulomb_friction', 0.0)
    dc = effects.get('viscous_damping_error', 0.0)
    dk = effects.get('stiffness_error', 0.0)
    k3 = effects.get('cubic_stiffness', 0.0)
    b = effects.get('backlash')

    def force(x, v):
        spring = K_D * x if b is None else K_D * math.copysign(max(abs(x) - b, 0.0), x)
        return C_D * v + spring + dc * v + dk * x + k3 * x ** 3 + fc * math.tanh(v / V_EPS)

    h = 1.0 / (fs * SUB)
    x = v = 0.0
    xs = np.empty(uf.size + 1)
    fo = np.empty(uf.size + 1)
    xs[0] = fo[0] = 0.0
    for i, ui in enumerate(uf.tolist()):
        a1 = -ui - force(x, v) / m
        xm, vm = x + 0.5 * h * v, v + 0.5 * h * a1
        a2 = -ui - force(xm, vm) / m
        x, v = x + h * vm, v + h * a2
        xs[i + 1] = x
        fo[i + 1] = force(x, v)
    idx = np.arange(n) * SUB + (0 if output_start else SUB)
    return _finish(rng, {'time': np.arange(n) / fs, 'base_accel': u}, u,
                   {'rel_disp': xs[idx], 'force': fo[idx]}, effects, fs)


def _finish(rng, data, u, outs, effects, fs):
    k = int(round(effects.get('time_delay', 0.0) * fs))
    for name, y in outs.items():
        if k:
            y = np.concatenate([np.full(k, y[0]), y[:-k]])
        if name in ('rel_disp', 'measured'):
            y = y + effects.get('sensor_bias', 0.0)
        data[name] = y + NOISE * np.std(y) * rng.standard_normal(y.size)
    for name in ('base_accel',):
        if name in data:
            data[name] = u + NOISE * np.std(u) * rng.standard_normal(u.size)
    return data


def actuator_record(effects, seed, interpolate=False, extra_step=False, output_start=False):
    """Actuator record (time, command, measured) of the Table 1 3-pole servo with ``effects``."""
    rng = np.random.default_rng(2000 + seed)
    fs, n = FS_HZ, int(DURATION_S * FS_HZ)
    u = _excitation(rng, n, fs, 15.0, 0.003)
    uf = _fine(u, interpolate, extra_step)
    num, den = continuous_actuator('3pole')
    a_m, b_m, c_m, _ = signal.tf2ss(num, den)
    ca, ca2 = c_m @ a_m, c_m @ a_m @ a_m
    dc = effects.get('coulomb_friction', 0.0)
    tv = effects.get('viscous_damping_error', 0.0)
    ka = effects.get('stiffness_error', 0.0)
    mu = effects.get('mass_error', 0.0)
    loop = any(k in effects for k in ('coulomb_friction', 'viscous_damping_error',
                                      'stiffness_error', 'mass_error'))
    h = 1.0 / (fs * SUB)
    bcol = b_m[:, 0]

    def deriv(x, ui):
        w = ui
        if loop:
            y, yd, ydd = float(c_m[0] @ x), float(ca[0] @ x), float(ca2[0] @ x)
            w -= tv * yd + ka * y + mu * ydd + dc * math.tanh(yd / V_EPS)
        return a_m @ x + bcol * w

    x = np.zeros(a_m.shape[0])
    ys = np.empty(uf.size + 1)
    ys[0] = 0.0
    for i, ui in enumerate(uf.tolist()):
        k1 = deriv(x, ui)
        x = x + h * deriv(x + 0.5 * h * k1, ui)
        ys[i + 1] = float(c_m[0] @ x)
    if 'velocity_saturation' in effects:
        ys = _rate_limited(ys, effects['velocity_saturation'], h)
    if 'backlash' in effects:
        ys = _play(ys, effects['backlash'])
    idx = np.arange(n) * SUB + (0 if output_start else SUB)
    return _finish(rng, {'time': np.arange(n) / fs, 'command': u}, u,
                   {'measured': ys[idx]}, effects, fs)


def _specimen_sizes():
    return {'coulomb_friction': 6.0, 'viscous_damping_error': 0.4 * C_D,
            'stiffness_error': 0.04 * K_D, 'mass_error': 0.04 * M_D,
            'cubic_stiffness': 2.7e7, 'backlash': 1.8e-4, 'sensor_bias': 3.5e-4,
            'time_delay': 4.0 / FS_HZ}


def _actuator_sizes():
    return {'coulomb_friction': 2.5e-4, 'viscous_damping_error': 0.0015,
            'stiffness_error': 0.04, 'mass_error': 1.5e-5, 'backlash': 2.5e-4,
            'velocity_saturation': 0.4, 'sensor_bias': 2.5e-4, 'time_delay': 4.0 / FS_HZ}


#: Set A (ZOH input; actuator with one more converter step): (scenario, effects).
SET_A = [('specimen', ()), ('specimen', ('coulomb_friction',)),
         ('specimen', ('stiffness_error',)), ('specimen', ('cubic_stiffness',)),
         ('specimen', ('mass_error',)), ('specimen', ('backlash',)),
         ('specimen', ('sensor_bias',)), ('specimen', ('time_delay',)),
         ('actuator', ()), ('actuator', ('coulomb_friction',)),
         ('actuator', ('stiffness_error',)), ('actuator', ('velocity_saturation',)),
         ('actuator', ('backlash',)), ('actuator', ('sensor_bias',))]
#: Set B (interpolated input, output read at the start of the step), pairs included.
SET_B = [('specimen', ()), ('specimen', ('backlash', 'sensor_bias')),
         ('specimen', ('coulomb_friction', 'sensor_bias')),
         ('specimen', ('viscous_damping_error', 'stiffness_error')),
         ('specimen', ('mass_error', 'time_delay')), ('specimen', ('cubic_stiffness',)),
         ('actuator', ()), ('actuator', ('coulomb_friction', 'sensor_bias')),
         ('actuator', ('backlash', 'sensor_bias')),
         ('actuator', ('stiffness_error', 'time_delay')), ('actuator', ('mass_error',)),
         ('actuator', ('viscous_damping_error',))]


def record(set_name, i):
    """Record ``i`` of set 'A' or 'B': (scenario, data, truth {name: value}, expected label)."""
    scenario, names = (SET_A if set_name == 'A' else SET_B)[i]
    sizes = _specimen_sizes() if scenario == 'specimen' else _actuator_sizes()
    truth = {k: sizes[k] for k in names}
    if set_name == 'A':
        conv = {'interpolate': False}
        if scenario == 'actuator':
            conv['extra_step'] = True
    else:
        conv = {'interpolate': True, 'output_start': scenario == 'actuator'}
    make = specimen_record if scenario == 'specimen' else actuator_record
    data = make(truth, i, **conv)
    expected = '+'.join(sorted(names, key=fx.EFFECT_NAMES.index)) if names else 'none'
    return scenario, data, truth, expected


def run_one(args):
    """Run the workflow on held-out record ``args`` = (set, index); return a summary row."""
    set_name, i = args
    t0 = time.perf_counter()
    scenario, data, truth, expected = record(set_name, i)
    res = run_discrepancy(scenario, data, plots=False)
    return {'set': set_name, 'index': i, 'scenario': scenario, 'expected': expected,
            'named': res['effect'], 'correct': res['effect'] == expected, 'truth': truth,
            'parameters': {k: v for par in res['parameters'].values() for k, v in par.items()
                           if k != 'unit'},
            'alignment_samples': res['alignment_samples'], 'gap_closed': res['gap_closed'],
            'best_candidate': res['best_candidate'], 'seconds': time.perf_counter() - t0}


def run_sets(workers=2, progress=None):
    """Run sets A and B; return {'A': {...}, 'B': {...}} with counts and rows."""
    jobs = [('A', i) for i in range(len(SET_A))] + [('B', i) for i in range(len(SET_B))]
    say = progress or (lambda msg: None)

    rows = run_with_progress(run_one, jobs, workers, 'held-out records', say, _line)
    rows.sort(key=lambda r: (r['set'], r['index']))
    out = {}
    for s in ('A', 'B'):
        rs = [r for r in rows if r['set'] == s]
        out[s] = {'records': len(rs), 'named': sum(r['correct'] for r in rs),
                  'target': 13 if s == 'A' else 11, 'rows': rs}
    return out


def _line(i, n, row):
    mark = 'ok ' if row['correct'] else 'BAD'
    return (f"[held-out {i}/{n}] {mark} set {row['set']} {row['scenario']:8s} "
            f"{row['expected']:40s} -> {row['named']} (alignment "
            f"{row['alignment_samples']:+.2f} samples, {row['seconds']:.1f} s)")
