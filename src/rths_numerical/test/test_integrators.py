"""Integrators: published spectral properties, stability, RTHS cycle (see integrators.py)."""

import math

import numpy as np
import pytest

from rths_numerical.integrators import (
    amplification_matrix,
    generalized_alpha_matrix,
    make_integrator,
    numerical_properties,
)


@pytest.mark.parametrize('name', ['cr', 'newmark'])
@pytest.mark.parametrize('omega_dt', [0.05, 0.3, 1.0, 2.5])
def test_trapezoidal_period_elongation_and_no_damping(name, omega_dt):
    """CR and Newmark average acceleration: the exact period error, no damping.

    CR and Newmark avg. acc.: T'/T = (Omega/2)/atan(Omega/2), spectral radius 1 (Chen-Ricles
    2008; Newmark 1959).
    """
    rho, xi, pe = numerical_properties(amplification_matrix(name, omega_dt, 1.0), omega_dt)
    expected = (omega_dt / 2) / math.atan(omega_dt / 2) - 1
    assert pe == pytest.approx(expected, rel=1e-9)
    assert abs(xi) < 1e-10
    assert rho == pytest.approx(1.0, abs=1e-10)


@pytest.mark.parametrize('rho_inf', [0.0, 0.3, 0.6, 1.0])
@pytest.mark.parametrize('omega_dt', [0.1, 1.0, 10.0, 1e3])
def test_kr_alpha_has_generalized_alpha_spectrum(rho_inf, omega_dt):
    """Kolay-Ricles 2014: KR-alpha's amplification eigenvalues equal generalized-alpha's."""
    kr = np.sort_complex(np.linalg.eigvals(amplification_matrix('kr_alpha', omega_dt, 1.0,
                                                                rho_inf=rho_inf)))
    ga = np.sort_complex(np.linalg.eigvals(generalized_alpha_matrix(omega_dt, 1.0, rho_inf)))
    assert np.allclose(kr, ga, atol=1e-6)


@pytest.mark.parametrize('rho_inf', [0.0, 0.5, 0.8, 1.0])
def test_kr_alpha_spectral_radius_at_infinity_and_damping(rho_inf):
    """rho(Omega -> inf) = rho_inf; numerical damping grows with Omega when rho_inf < 1."""
    rho_big, _, _ = numerical_properties(amplification_matrix('kr_alpha', 1e6, 1.0,
                                                              rho_inf=rho_inf), 1e6)
    assert rho_big == pytest.approx(rho_inf, abs=2e-3)
    _, xi_small, _ = numerical_properties(amplification_matrix('kr_alpha', 0.2, 1.0,
                                                               rho_inf=rho_inf), 0.2)
    _, xi_mid, _ = numerical_properties(amplification_matrix('kr_alpha', 1.0, 1.0,
                                                             rho_inf=rho_inf), 1.0)
    if rho_inf < 1:
        assert 0 < xi_small < xi_mid
    else:
        assert abs(xi_mid) < 1e-9


@pytest.mark.parametrize('name', ['cr', 'kr_alpha'])
def test_unconditionally_stable_on_stiff_system(name):
    """Every integrator is stable up to Omega = 1e6 and on a stiff 2-DOF system.

    Spectral radius <= 1 for every Omega up to 1e6; a stiff 2-DOF system stepped at 50 x its
    shortest period (central difference needs dt < T/pi) stays bounded over many beat periods.
    (CR overshoots by O(Omega) in a stiff mode started with an equilibrium acceleration, a known
    property of explicit model-based schemes, but does not grow.)
    """
    for omega_dt in np.logspace(-2, 6, 33):
        rho, _, _ = numerical_properties(amplification_matrix(name, omega_dt, 1.0, zeta=0.0,
                                                              rho_inf=0.5), omega_dt)
        assert rho <= 1 + 1e-9
    M = np.diag([1.0, 1.0])
    K = np.array([[1e8 + 10.0, -1e8], [-1e8, 1e8]])
    w_max = math.sqrt(np.max(np.linalg.eigvalsh(K)))
    dt = 50 * 2 * math.pi / w_max
    integ = make_integrator(name, M, np.zeros((2, 2)), K, dt, rho_inf=0.5)
    integ.set_state([1.0, -1.0], [0.0, 0.0])
    peaks = []
    for _ in range(4):
        peak = 0.0
        for _ in range(1000):
            peak = max(peak, float(np.max(np.abs(integ.step(np.zeros(2))))))
        peaks.append(peak)
    assert np.all(np.isfinite(peaks))
    assert max(peaks[2:]) <= 1.01 * max(peaks[:2])


@pytest.mark.parametrize('name', ['cr', 'kr_alpha', 'newmark'])
def test_sdof_free_vibration_accuracy(name):
    """Damped SDOF free vibration at 1024 Hz matches the closed form within 1 % of amplitude."""
    m, f, z = 2.0, 2.81, 0.05
    w = 2 * math.pi * f
    dt = 1 / 1024
    integ = make_integrator(name, [[m]], [[2 * z * m * w]], [[m * w * w]], dt, rho_inf=0.9)
    integ.set_state([0.01], [0.0])
    n = 1024
    d = np.zeros(n)
    for k in range(n):
        d[k] = integ.step(np.zeros(1))[0]
    t = np.arange(1, n + 1) * dt
    wd = w * math.sqrt(1 - z * z)
    exact = 0.01 * np.exp(-z * w * t) * (np.cos(wd * t) + z * w / wd * np.sin(wd * t))
    # CR's start-up error is O(Omega) (its velocity lags half a step), no drift after it
    assert np.max(np.abs(d - exact)) < 0.01 * 0.01


@pytest.mark.parametrize('name', ['cr', 'kr_alpha'])
def test_predict_is_explicit(name):
    """The predicted displacement does not depend on the load/force of step k+1."""
    integ = make_integrator(name, np.eye(2), 0.1 * np.eye(2), np.array([[2.0, -1], [-1, 1]]),
                            0.01)
    integ.set_state([0.1, 0.2], [0.0, 0.3])
    d1 = integ.predict(np.array([5.0, 5.0])).copy()
    d2 = integ.predict(np.array([-9.0, 1.0])).copy()
    assert np.array_equal(d1, d2)


def test_measured_force_enters_equilibrium():
    """A spring specimen through correct() shifts the SDOF frequency.

    A spring specimen r = k_e d through correct() shifts the SDOF frequency to
    sqrt((k + k_e)/m) (CR, 1024 Hz, 4 s).
    """
    m, k, ke = 1.0, (2 * math.pi * 2) ** 2, (2 * math.pi * 2) ** 2 * 1.25
    dt = 1 / 1024
    integ = make_integrator('cr', [[m]], [[0.0]], [[k]], dt)
    integ.set_state([0.01], [0.0], r=[ke * 0.01])
    n = 4096
    d = np.zeros(n)
    for i in range(n):
        d[i] = integ.predict()[0]
        integ.correct(np.zeros(1), np.array([ke * d[i]]))
    spec = np.abs(np.fft.rfft(d * np.hanning(n), 16 * n))
    f_peak = np.fft.rfftfreq(16 * n, dt)[np.argmax(spec)]
    assert f_peak == pytest.approx(math.sqrt((k + ke) / m) / (2 * math.pi), rel=0.01)


def test_bad_inputs():
    """Shape and parameter errors name the problem."""
    with pytest.raises(ValueError, match='rho_inf'):
        make_integrator('kr_alpha', [[1.0]], [[0.0]], [[1.0]], 0.01, rho_inf=1.5)
    with pytest.raises(ValueError, match='integrator'):
        make_integrator('rk4', [[1.0]], [[0.0]], [[1.0]], 0.01)
    with pytest.raises(ValueError, match='K has shape'):
        make_integrator('cr', np.eye(2), np.eye(2), np.eye(3), 0.01)
