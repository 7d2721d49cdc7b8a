"""The benchmark control plant (Silva et al. 2020) in the simulated plant."""

import numpy as np
from scipy import signal

from rths_actuator_bridge import silva2020
from rths_actuator_bridge.channels import CHANNELS
from rths_actuator_bridge.simulated import silva2020_plant


def test_transfer_function_matches_the_issue_figures():
    # Issue 13 (from the paper's Fig. 9): uncompensated ~25 ms lag, |G| ~0.63 at 10 Hz.
    num, den = silva2020.transfer_function()
    w = 2 * np.pi * np.array([1e-3, 10.0])
    _, h = signal.freqs(num, den, w)
    assert abs(h[0]) > 0.99
    assert abs(abs(h[1]) - 0.63) < 0.01
    lag_ms = -np.angle(h[1]) / w[1] * 1e3
    assert 18.0 < lag_ms < 26.0


def test_state_space_equals_transfer_function():
    a, b, c, d = silva2020.state_space()
    num, den = silva2020.transfer_function()
    w = 2 * np.pi * np.array([0.5, 5.0, 20.0, 80.0])
    _, h_tf = signal.freqs(num, den, w)
    ss_num, ss_den = signal.ss2tf(a, b, c[:1], d[:1])
    _, h_ss = signal.freqs(ss_num.ravel(), ss_den, w)
    assert np.allclose(h_ss, h_tf, rtol=1e-8)


def test_simulated_plant_hook_force_is_specimen_force():
    plant = silva2020_plant(displacement_noise_m=0.0, force_noise_n=0.0)
    assert plant.dt == 1.0 / 4096.0 and plant.n_states == 5
    t = np.arange(8192) / 4096.0
    u = 2e-3 * np.sin(2 * np.pi * 4.0 * t)
    out = plant.simulate(u)
    p = silva2020.Silva2020Params()
    force = p.m_e * out['table_accel'] + p.c_e * out['table_vel'] + p.k_e * out['table_disp']
    assert np.allclose(out['force'], force, atol=1e-6 * np.max(np.abs(force)))
    assert set(out) == set(CHANNELS)
    # exact ZOH: equals scipy's discretisation of G(s); the plant reports the end of
    # each sample (the project's timing), lfilter its start
    num, den = silva2020.transfer_function()
    bd, ad, _ = signal.cont2discrete((num, den), plant.dt, 'zoh')
    ref = signal.lfilter(np.ravel(bd), ad, u)
    assert np.allclose(out['table_disp'][:-1], ref[1:], atol=1e-9 * np.max(np.abs(ref)))


def test_sensor_noise_and_perturbation():
    plant = silva2020_plant(seed=3)
    out = plant.simulate(np.zeros(40000))
    assert abs(np.std(out['table_disp']) - 1.6e-5) < 0.05 * 1.6e-5
    assert abs(np.std(out['force']) - 2.18) < 0.05 * 2.18
    rng = np.random.default_rng(0)
    draws = [silva2020.perturbed(rng) for _ in range(200)]
    k_e = np.array([d.k_e for d in draws])
    assert abs(np.std(k_e) - 50e3) < 10e3
    d = draws[0]
    assert d.c_e == 2 * d.zeta_e * np.sqrt(d.k_e * d.m_e)
    assert silva2020_plant(d).a_c[4, 3] == -d.k_e / d.m_e


def test_converter_quantises_and_saturates():
    q = silva2020.QUANTUM
    assert silva2020.converter(5.0) == 3.8 // q * q or abs(silva2020.converter(5.0) - 3.8) < q
    assert silva2020.converter(-9.0) <= -3.8 + q
    x = np.array([0.3 * q, 0.7 * q, 1e-3])
    assert np.allclose(silva2020.converter(x), [0.0, q, np.round(1e-3 / q) * q])
