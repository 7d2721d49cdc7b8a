"""Adaptive compensators: each guard, and each method's convergence on a plant change."""

import math

import numpy as np
import pytest
from scipy import signal

from rths_compensator.adaptive import (
    METHODS,
    Amb,
    Ats,
    FixedFir,
    Guards,
    RlsFir,
    make_method,
    split_fir,
)
from rths_compensator.design import design_fir
from rths_compensator.filters import MultiChannelFilter
from rths_compensator.indicators import relative_rms_pct
from rths_compensator.plants import discrete_actuator
from rths_numerical.signals import blwn

FS = 1024.0


@pytest.fixture(scope='module')
def setup():
    b, a = discrete_actuator('3pole', FS)
    design = design_fir((b, a), n_taps=32, fc_hz=64.0, scheme='ls', fs_hz=FS, zero_tol=0.98)
    return (b, a), design


class Plant:
    """The ZOH 3-pole model stepped one sample at a time, with a settable gain factor."""

    def __init__(self, b, a, noise=2e-6, seed=0):
        self.filter = MultiChannelFilter(b, a)
        self.gain = 1.0
        self.rng = np.random.default_rng(seed)
        self.noise = noise

    def step(self, u):
        return self.gain * float(self.filter.step(np.array([u]))[0]) \
            + self.noise * self.rng.standard_normal()


def closed_loop(method, plant, target, change_at=None, gain=1.0, measured_fn=None):
    """Run ``method`` on ``plant``; return the measured displacement per step."""
    y = np.zeros(target.size)
    prev = None
    for k, x in enumerate(target):
        if k == change_at:
            plant.gain = gain
        u = method.step(x, prev)
        prev = plant.step(u) if measured_fn is None else measured_fn(k, u)
        y[k] = prev
    return y


def target(seconds, seed=5, peak=5.08e-3):
    return blwn(seconds, FS, 10.0, peak, np.random.default_rng(seed), taper_s=0.5)


def test_fixed_fir_is_the_designed_filter(setup):
    _, design = setup
    x = target(1.0)
    fir = make_method('fir', design)
    ref = signal.lfilter(design.taps, design.denominator, x)
    out = np.array([fir.step(v) for v in x])
    np.testing.assert_allclose(out, ref, rtol=1e-10, atol=1e-14)
    assert fir.status.state == 'fixed'


def test_split_fir_recovers_h(setup):
    plant, design = setup
    h, pre_b, pre_a = split_fir(design, plant)
    np.testing.assert_allclose(np.convolve(pre_b, h), design.taps, rtol=1e-9, atol=1e-9)
    with pytest.raises(ValueError, match='not an FIR compensator'):
        split_fir(design.__class__('ls', design.taps + 1.0, design.denominator, FS), plant)


@pytest.mark.parametrize('name', ['rls_fir', 'ats', 'amb'])
def test_low_excitation_freezes(setup, name):
    plant, design = setup
    method = make_method(name, design, plant)
    c0 = method.coefficients()
    x = target(3.0, peak=1e-5)            # far below the 0.254 mm RMS threshold
    closed_loop(method, Plant(*plant), x)
    assert method.status.state == 'frozen'
    assert 'excitation' in method.status.reason
    np.testing.assert_array_equal(method.coefficients(), c0)


@pytest.mark.parametrize('name', ['rls_fir', 'ats', 'amb'])
def test_fault_flag_freezes_then_releases(setup, name):
    plant, design = setup
    method = make_method(name, design, plant)
    method.flag_fault('bridge: hold')
    c0 = method.coefficients()
    p = Plant(*plant)
    p.gain = 0.8                          # a plant change the method would adapt to
    closed_loop(method, p, target(2.0))
    assert method.status == method.status.__class__('frozen', 'fault flagged: bridge: hold')
    np.testing.assert_array_equal(method.coefficients(), c0)
    method.clear_fault()
    closed_loop(method, p, target(2.0, seed=6))
    assert method.status.state == 'adapting'
    assert not np.array_equal(method.coefficients(), c0)


@pytest.mark.parametrize('name', ['rls_fir', 'ats', 'amb'])
def test_bounds_and_rate_limits_hold(setup, name):
    plant, design = setup
    guards = Guards(fallback_pct=1e9)     # let it adapt on nonsense without falling back
    method = make_method(name, design, plant, guards)
    x = target(4.0)
    coefs = []

    def nonsense(k, u):                    # measured = 3x the command, sign-flipped half the time
        coefs.append(method.coefficients())
        return (3.0 if (k // 500) % 2 else -3.0) * u
    closed_loop(method, Plant(*plant), x, measured_fn=nonsense)
    c = np.array(coefs)
    assert np.all(c >= method.lower - 1e-12) and np.all(c <= method.upper + 1e-12)
    steps = np.abs(np.diff(c, axis=0))
    assert np.all(steps <= method.max_step * (1 + 1e-9) + 1e-15)
    assert np.any(steps > 0)


@pytest.mark.parametrize('name', ['rls_fir', 'ats', 'amb'])
def test_tracking_error_falls_back_to_the_designed_fir(setup, name):
    plant, design = setup
    method = make_method(name, design, plant)
    fir = FixedFir(design.taps, design.denominator)
    x = target(3.0)
    out = []

    def inverted(k, u):                   # a wiring fault: the measured sign is flipped
        out.append((u, fir.step(x[k])))
        return -u
    closed_loop(method, Plant(*plant), x, measured_fn=inverted)
    assert method.fallen_back and method.status.state == 'fallback'
    assert 'tracking error' in method.status.reason
    k_fb = next(i for i, (u, f) in enumerate(out) if i > 1024 and u == f)
    assert all(u == f for u, f in out[k_fb:])         # the FIR's command from then on


@pytest.mark.parametrize('name', ['rls_fir', 'ats', 'amb'])
def test_non_finite_input_never_reaches_the_output(setup, name):
    plant, design = setup
    method = make_method(name, design, plant)
    x = target(2.0)
    p = Plant(*plant)
    closed_loop(method, p, x[:1500])
    u = method.step(float('nan'), p.step(0.0))
    assert math.isfinite(u) and method.status.state == 'fallback'
    assert 'non-finite target' in method.status.reason
    u = method.step(x[1501], float('inf'))
    assert math.isfinite(u)
    m2 = make_method(name, design, plant)
    closed_loop(m2, Plant(*plant), x[:100])
    assert math.isfinite(m2.step(x[100], float('nan')))
    assert 'non-finite measurement' in m2.status.reason


@pytest.fixture(scope='module')
def gain_step(setup):
    """Target, change step, after-window and the fixed FIR's error: the gain drops 15 %."""
    plant, design = setup
    x = target(12.0)
    kc, after = 6 * 1024, slice(9 * 1024, 12 * 1024)
    y = closed_loop(make_method('fir', design), Plant(*plant), x, change_at=kc, gain=0.85)
    return x, kc, after, relative_rms_pct(x[after], y[after])


@pytest.mark.parametrize('name', ['rls_fir', 'ats', 'amb'])
def test_converges_after_a_plant_change(setup, gain_step, name):
    """After the actuator gain drops 15 % the fixed FIR is ~15 % off; each method recovers."""
    plant, design = setup
    x, kc, after, fir_error = gain_step
    method = make_method(name, design, plant)
    y = closed_loop(method, Plant(*plant), x, change_at=kc, gain=0.85)
    error = relative_rms_pct(x[after], y[after])
    assert not method.fallen_back
    assert fir_error > 10.0
    limit = {'rls_fir': 1.0, 'ats': 8.0, 'amb': 1.0}[name]   # ATS: a 2nd-order model
    assert error < limit, (fir_error, error)


def test_make_method_errors(setup):
    plant, design = setup
    assert set(METHODS) == {'fir', 'rls_fir', 'ats', 'amb', 'pi_lead'}
    with pytest.raises(ValueError, match='unknown'):
        make_method('lms', design, plant)
    with pytest.raises(ValueError, match='needs the identified plant'):
        make_method('ats', design)
    with pytest.raises(ValueError, match='forgetting'):
        RlsFir(design, plant, forgetting=1.5)
    assert isinstance(make_method('ats', design, plant), Ats)
    assert isinstance(make_method('amb', design, plant), Amb)


def test_initial_coefficients_come_from_the_plant(setup):
    plant, design = setup
    ats = Ats(design, plant)
    # delay of the 3-pole model over 0-10 Hz is 15.7 ms (README, bench compensators)
    assert ats.coefficients()[1] == pytest.approx(0.0157, abs=0.001)
    amb = Amb(design, plant)
    theta = amb.coefficients()
    assert theta[0] == pytest.approx(1.0, abs=0.02)
    # all-pole model: 1/T(s) = prod(s - p)/K, so theta_1 = sum(1/-p_i) = 0.0157 s
    assert theta[1] == pytest.approx(0.0157, rel=0.1)


def test_channel_methods_from_params(setup, tmp_path):
    from rths_compensator.adaptive import ChannelMethods, methods_from_params
    from rths_compensator.identification import ArxModel, save_plant

    (b, a), design = setup
    params = {'scheme': 'ls', 'fs_hz': FS, 'taps': design.taps.tolist(),
              'denominator': design.denominator.tolist()}
    fir = methods_from_params(params, 2)
    assert isinstance(fir, ChannelMethods) and fir.status.state == 'fixed'
    with pytest.raises(ValueError, match='provenance.plant'):
        methods_from_params(dict(params, method='amb'), 1)
    with pytest.raises(ValueError, match='unknown'):
        methods_from_params(dict(params, method='lms'), 1)
    path = tmp_path / 'plant.yaml'
    save_plant(path, ArxModel(a=a, b=b, d=0, fs_hz=FS))
    amb = methods_from_params(dict(params, method='amb', provenance={'plant': str(path)}), 2)
    x = target(2.0)
    plants = [Plant(b, a), Plant(b, a)]
    prev = applied = None
    for k, v in enumerate(x):
        cmd = amb.step(np.array([v, -v]), prev, applied)
        prev = [p.step(c) for p, c in zip(plants, cmd, strict=True)]
        applied = cmd if k < 1500 else cmd + 1e-3   # from 1500 on the bridge holds/limits
    assert amb.coefficients().size == 8
    assert amb.status.state == 'frozen' and 'bridge changed the command' in amb.status.reason


def test_rls_fir_adapts_a_short_correction_of_a_long_fir(setup, gain_step):
    """A 128-tap H: a 16-tap correction C (H = H0 (1 + C)) adapts; the gain drop is followed."""
    plant, _ = setup
    x, kc, after, fir_error = gain_step
    design = design_fir(plant, n_taps=128, fc_hz=64.0, scheme='ls', fs_hz=FS, zero_tol=0.98)
    method = RlsFir(design, plant)
    assert method.correction and method.n_adapt == 16
    y = closed_loop(method, Plant(*plant), x, change_at=kc, gain=0.85)
    assert method.P.shape == (16, 16) and method.coefficients().size == 128 + 15
    assert not method.fallen_back and np.all(np.abs(method.c) <= 2.0)
    assert relative_rms_pct(x[after], y[after]) < 1.0 < 10.0 < fir_error


def test_rls_fir_up_to_n_full_taps_adapts_every_tap(setup):
    plant, design = setup
    x = target(3.0)
    runs = [closed_loop(RlsFir(design, plant, n_full=n_full), Plant(*plant), x,
                        change_at=1024, gain=0.9) for n_full in (32, 1000)]
    assert np.array_equal(runs[0], runs[1])
    assert not RlsFir(design, plant).correction and RlsFir(design, plant, n_full=16).correction
    with pytest.raises(ValueError, match='n_correction'):
        RlsFir(design, plant, n_full=16, n_correction=0)


def test_solve_spd3_matches_numpy_and_refuses_ill_conditioned_systems():
    from rths_compensator.adaptive import solve_spd3
    rng = np.random.default_rng(3)
    for cond in (1.0, 1e3, 1e8, 1e11, 0.9e12):
        q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
        a = q @ np.diag([1.0, math.sqrt(cond), cond]) @ q.T * 7.5
        a = (a + a.T) / 2
        b = rng.standard_normal(3)
        x = solve_spd3(a.tolist(), b.tolist())
        assert x is not None
        np.testing.assert_allclose(a @ np.array(x), b, atol=1e-12 * cond * np.abs(b).max())
    np.testing.assert_allclose(solve_spd3(np.diag([2.0, 2.0, 2.0]).tolist(), [2.0, 4.0, 6.0]),
                               [1.0, 2.0, 3.0], rtol=1e-15)
    assert solve_spd3(np.diag([1.0, 1.0, 1e-13]).tolist(), [1.0, 1.0, 1.0]) is None
    q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    rotated = q @ np.diag([1.0, 1e6, 1.1e12]) @ q.T      # cond 1.1e12: just over the limit
    assert solve_spd3(((rotated + rotated.T) / 2).tolist(), [1.0, 1.0, 1.0]) is None
    assert solve_spd3(np.diag([1.0, -1.0, 1.0]).tolist(), [1.0, 1.0, 1.0]) is None
    assert solve_spd3(np.zeros((3, 3)).tolist(), [1.0, 1.0, 1.0]) is None


def test_ats_keeps_its_window_normal_equations_exact(setup):
    """The rank-1 kept normal equations equal the window's, summed anew, at any step."""
    plant, design = setup
    method = Ats.from_design(design, plant)
    b, a = plant
    sim = Plant(b, a, seed=4)
    x = target(3.3)
    prev = None
    for k in range(x.size):
        prev = sim.step(method.step(x[k], prev))
        if k in (100, method.n_window - 1, method.n_window + 7, 2 * method.n_window + 300):
            w = method._rows[method._p:method._p + method.n_window]
            exact = w[:, :3].T @ w
            np.testing.assert_allclose(method._normal, exact, rtol=1e-9,
                                       atol=1e-12 * np.abs(exact).max())


@pytest.mark.parametrize('size', [3, 4, 40])
def test_clip_step_is_np_clip_on_short_and_long_vectors(size):
    from rths_compensator.adaptive import _clip_step
    rng = np.random.default_rng(size)
    old, new = rng.standard_normal(size), 3 * rng.standard_normal(size)
    lower, upper = old - rng.uniform(0, 2, size), old + rng.uniform(0, 2, size)
    for max_step in (0.5, rng.uniform(0, 1, size)):
        want = np.clip(np.clip(new, old - max_step, old + max_step), lower, upper)
        np.testing.assert_array_equal(_clip_step(new.copy(), old, lower, upper, max_step), want)
    new[1] = np.nan
    assert np.isnan(_clip_step(new.copy(), old, lower, upper, 0.5)[1])


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_in_place_clip_equals_clip_step_bit_for_bit(seed):
    """rls_fir's in-place clip (skipping both clips when they cannot act) is _clip_step."""
    from rths_compensator.adaptive import _Clip, _clip_step
    rng = np.random.default_rng(seed)
    size, max_step = 16, 1e-3
    lower, upper = -0.05 * rng.uniform(0.5, 1.0, size), 0.05 * rng.uniform(0.5, 1.0, size)
    clip = _Clip(lower, upper, max_step)
    x, ref = np.zeros(size), np.zeros(size)
    skipped = touched = 0
    for k in range(3000):
        scale = max_step * (0.1 if k % 500 < 400 else 3.0)      # mostly small, some large
        dx = scale * rng.standard_normal(size) + (1e-4 if k < 1500 else -1e-4)
        skipped += clip.room > clip.slack and np.max(np.abs(dx)) <= max_step
        want = _clip_step(ref + dx, ref, lower, upper, max_step)
        ref = want
        touched += bool(np.any(want == lower) or np.any(want == upper))
        clip.add(x, dx)
        assert np.array_equal(x, want), k
    assert 500 < skipped < 2900      # both paths ran
    assert touched > 100             # the bounds acted
    dx[3] = np.nan
    clip.add(x, dx)
    assert np.isnan(x[3]) and np.all(np.isfinite(np.delete(x, 3)))
