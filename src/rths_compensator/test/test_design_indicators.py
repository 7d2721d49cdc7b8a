"""Defining properties of every compensator (eq. 2, 4, 8, 12, 14, 28-36) and indicators."""

import numpy as np
import pytest
from scipy import signal

from rths_compensator import design as dsg
from rths_compensator.identification import ArxModel, factor_zeros
from rths_compensator.indicators import bode, relative_rms_pct, time_delay_from_data, time_delay_ms
from rths_compensator.plants import discrete_actuator

FS = 1024.0


@pytest.fixture(scope='module')
def plant():
    """Return a plant like the seed's eq. 41: 3-pole model with an extra unstable zero at 1.664."""
    b, a = discrete_actuator('3pole', FS)
    # factor (-1/1.664 + z^-1) has its zero at z = 1.664; scaled to keep unit DC gain
    b = np.convolve(b, [-1 / 1.664, 1.0]) / (1 - 1 / 1.664)
    return ArxModel(a=a, b=b, d=0, fs_hz=FS)


def _frf(num, den, freqs):
    return signal.freqz(num, den, worN=freqs, fs=FS)[1]


def test_plant_fixture_has_two_unstable_zeros(plant):
    _, b_minus = factor_zeros(plant.b)
    assert b_minus.size == 3  # -3.56 (sampling zero) and 1.664
    assert plant.dc_gain() == pytest.approx(1.0, abs=1e-9)


def test_zpetc_compensated_phase_is_q_sample_delay(plant):
    """Eq. 13: T G_ZPETC = B-*(z^-1) B-(z^-1)/B-*(1)^2 -> zero phase apart from z^-q."""
    comp = dsg.design_zpetc(plant)
    num, den = dsg.compensated(plant, comp)
    freqs = np.linspace(1.0, 500.0, 300)
    h = _frf(num, den, freqs) * np.exp(1j * 2 * np.pi * freqs / FS * comp.info['q'])
    assert np.max(np.abs(np.imag(h))) < 1e-9 * np.max(np.abs(h))
    assert np.all(np.real(h) > 0)
    assert abs(np.sum(num) / np.sum(den) - 1) < 1e-9


def test_zmetc_compensated_magnitude_is_one(plant):
    """Eq. 15 / Appendix III: |T G_ZMETC| = 1 at all frequencies."""
    num, den = dsg.compensated(plant, dsg.design_zmetc(plant))
    freqs = np.linspace(0.0, 512.0, 400)
    np.testing.assert_allclose(np.abs(_frf(num, den, freqs)), 1.0, atol=1e-9)


def test_npz_ignore_unit_dc_gain_and_stable(plant):
    """Eq. 9: T G_NPZ = B-*/B-*(1): unit steady-state gain."""
    comp = dsg.design_npz(plant)
    num, den = dsg.compensated(plant, comp)
    assert np.sum(num) / np.sum(den) == pytest.approx(1.0, abs=1e-9)
    assert comp.denominator.size == 1 or np.max(np.abs(np.roots(comp.denominator))) < 1


def test_inverse_compensation_formula():
    comp = dsg.design_inverse(FS, delay_ms=15.0)
    tau = 15e-3 * FS
    np.testing.assert_allclose(comp.taps, [tau + 1, -tau])
    # it cancels the first-order delay model of eq. 1 exactly
    t_num, t_den = [1.0], [tau + 1, -tau]
    x = np.random.default_rng(0).standard_normal(200)
    y = signal.lfilter(t_num, t_den, signal.lfilter(comp.taps, [1.0], x))
    np.testing.assert_allclose(y, x, atol=1e-9)


@pytest.mark.parametrize('kind', ['3pole', '4pole'])
@pytest.mark.parametrize('alpha', [3, 5, 7])
def test_mff_unit_dc_gain_stable_and_reduces_delay(kind, alpha):
    comp = dsg.design_mff(kind, alpha, FS)
    assert np.sum(comp.taps) / np.sum(comp.denominator) == pytest.approx(1.0, rel=1e-6)
    assert np.max(np.abs(np.roots(comp.denominator))) < 1
    b, a = discrete_actuator(kind, FS)
    plain = time_delay_ms(b, a, FS, 20.0)
    comped = time_delay_ms(np.convolve(b, comp.taps), np.convolve(a, comp.denominator),
                           FS, 20.0)
    assert 0 < comped < plain / alpha * 1.5


@pytest.mark.parametrize('scheme', ['ls', 'wls', 'mm'])
@pytest.mark.parametrize('n_taps, fc', [(25, 32.0), (50, 64.0)])
def test_fir_constraints_held(plant, scheme, n_taps, fc):
    """Eq. 34 (unit DC gain) exactly; eq. 35-36 as |T_com - 1| <= epsilon in the passband."""
    eps = 0.01
    comp = dsg.design_fir(plant, n_taps, fc, scheme, eps)
    num, den = dsg.compensated(plant, comp)
    assert np.sum(num) / np.sum(den) == pytest.approx(1.0, abs=1e-8)
    freqs = np.linspace(0.0, fc, 200)
    err = np.abs(_frf(num, den, freqs) - 1.0)
    assert np.max(err) <= eps * 1.02
    mag_db = 20 * np.log10(np.abs(_frf(num, den, freqs)))
    assert np.max(np.abs(mag_db)) <= 20 * np.log10(1 + eps) * 1.01
    assert comp.taps.size == n_taps + plant.na
    assert np.max(np.abs(np.roots(comp.denominator))) < 1 if comp.denominator.size > 1 else True


def test_fir_ls_is_least_squares_optimum_when_unconstrained(plant):
    """With a loose epsilon LS is the equality-constrained least-squares solution."""
    comp = dsg.design_fir(plant, 30, 32.0, 'ls', epsilon=10.0)
    assert 'inactive' in comp.info['solver']
    # perturbing the taps along the DC-gain null space cannot lower the objective
    _, b_minus = factor_zeros(plant.b)
    freqs = np.linspace(0, FS / 2, 513)
    num, den = dsg.compensated(plant, comp)
    base = np.sum(np.abs(_frf(num, den, freqs) - 1) ** 2)
    rng = np.random.default_rng(0)
    for _ in range(5):
        delta = rng.standard_normal(30)
        delta -= delta.mean()
        taps2 = comp.taps + np.convolve(plant.a, delta) * 1e-4 / np.sum(b_minus)
        num2 = np.convolve(plant.b, taps2)
        assert np.sum(np.abs(_frf(num2, den, freqs) - 1) ** 2) >= base * (1 - 1e-9)


def test_mm_not_worse_than_ls_in_max_error(plant):
    ls = dsg.design_fir(plant, 40, 64.0, 'ls', 0.01)
    mm = dsg.design_fir(plant, 40, 64.0, 'mm', 0.01)
    assert mm.info['max_error_all'] <= ls.info['max_error_all'] * 1.09  # 8-gon objective


def test_fir_refuses_infeasible_epsilon(plant):
    with pytest.raises(ValueError, match='infeasible'):
        dsg.design_fir(plant, 5, 200.0, 'ls', epsilon=1e-4)
    with pytest.raises(ValueError, match='infeasible'):
        dsg.design_fir(plant, 5, 200.0, 'mm', epsilon=1e-4)


def test_fir_improves_delay_of_seed_like_plant(plant):
    comp = dsg.design_fir(plant, 100, 64.0, 'ls')
    pred = dsg.predict(plant, comp, 20.0)
    assert abs(pred['delay_ms']) < 0.2
    assert time_delay_ms(plant.num, plant.a, FS, 20.0) > 15


def test_dispatch_and_unknown_scheme(plant):
    for scheme in dsg.ALL_SCHEMES:
        opts = {'n_taps': 25, 'fc_hz': 32.0} if scheme in dsg.FIR_SCHEMES else {}
        comp = dsg.design(plant, scheme, **opts)
        assert comp.scheme == scheme and np.all(np.isfinite(comp.taps))
    with pytest.raises(ValueError):
        dsg.design(plant, 'magic')


def test_time_delay_of_pure_delay_and_from_data():
    num = np.r_[np.zeros(10), 1.0]
    assert time_delay_ms(num, [1.0], FS, 30.0) == pytest.approx(10 / FS * 1e3, rel=1e-9)
    rng = np.random.default_rng(0)
    x = rng.standard_normal(40000)
    y = signal.lfilter(num, [1.0], x)
    assert time_delay_from_data(x, y, FS, 30.0) == pytest.approx(10 / FS * 1e3, rel=5e-3)
    b, a = discrete_actuator('3pole', FS)
    y = signal.lfilter(b, a, x)
    assert time_delay_from_data(x, y, FS, 20.0) == pytest.approx(
        time_delay_ms(b, a, FS, 20.0), abs=0.1)


def test_relative_rms_eq43():
    d = np.array([1.0, -1.0, 2.0])
    assert relative_rms_pct(d, d) == 0.0
    assert relative_rms_pct(d, 1.1 * d) == pytest.approx(10.0)
    with pytest.raises(ValueError):
        relative_rms_pct(np.zeros(3), d)


def test_bode_helper():
    f, mag, ph, delay = bode([0.0, 1.0], [1.0], FS, np.array([0.0, 10.0, 100.0]))
    np.testing.assert_allclose(mag, 0.0, atol=1e-12)
    assert delay[1] == pytest.approx(1e3 / FS)
    assert np.isnan(delay[0])


def test_auto_design_picks_a_good_candidate(plant):
    comp, table = dsg.auto_design(plant, 20.0, taps=(25, 50), fc_factors=(2.0,))
    best = table[0]
    assert best['score'] == min(r['score'] for r in table)
    assert abs(best['delay_ms']) < 0.5 and comp.scheme == best['scheme']


def _full_minimax_lp(plant, n_taps, fc, eps, n_grid=257):
    """Return the MM LP of design_fir with every row at once (one linprog): its optimal t."""
    _, b_minus = factor_zeros(plant.b)
    bmu = b_minus / np.sum(b_minus)
    m = dsg._fir_matrix(bmu, 0, n_taps, np.linspace(0, FS / 2, n_grid), FS)
    f_pass = np.linspace(0.0, fc, max(8, int(np.ceil(fc / (FS / 4096))) + 1))
    mp = dsg._fir_matrix(bmu, 0, n_taps, f_pass, FS)
    rot = dsg._polygon(8)
    ro = np.real(rot[:, None, None] * m[None]).reshape(-1, n_taps)
    rp = np.real(rot[:, None, None] * mp[None]).reshape(-1, n_taps)
    a_ub = np.vstack([np.hstack([ro, -np.ones((ro.shape[0], 1))]),
                      np.hstack([rp, np.zeros((rp.shape[0], 1))])])
    b_ub = np.r_[np.repeat(np.real(rot), m.shape[0]),
                 0.97 * eps * np.cos(np.pi / 8) + np.repeat(np.real(rot), mp.shape[0])]
    x, status = dsg._linprog_free(np.r_[np.zeros(n_taps), 1.0], a_ub, b_ub,
                                  np.r_[np.ones(n_taps), 0.0][None, :], [1.0])
    assert status == 0
    return x[-1]


@pytest.mark.parametrize('lp_method', ['highs', 'highs-ds'])
def test_mm_cutting_planes_reach_the_full_lp_optimum(plant, lp_method):
    """The cutting-plane MM (warm-started HiGHS or repeated linprog) solves the same LP."""
    t_full = _full_minimax_lp(plant, 40, 64.0, 0.005)
    comp = dsg.design_fir(plant, 40, 64.0, 'mm', 0.005, lp_method=lp_method)
    assert 'cutting planes' in comp.info['solver']
    # the polygon objective of the design (from its T_com) equals the full LP's optimum
    num, den = dsg.compensated(plant, comp)
    t_com = _frf(num, den, np.linspace(0, FS / 2, 257))
    rot = dsg._polygon(8)
    t_design = np.max(np.real(rot[:, None] * (t_com[None, :] - 1.0)))
    assert t_design == pytest.approx(t_full, rel=1e-5)


def test_zero_tol_keeps_lightly_damped_zeros_out_of_the_denominator():
    """Zeros with modulus >= zero_tol go to B-*: G = A* H/B+* then has no such poles."""
    b, a = discrete_actuator('3pole', FS)
    r, th = 0.995, 2 * np.pi * 150.0 / FS          # lightly damped pair at 150 Hz
    b = np.convolve(b, [1.0, -2 * r * np.cos(th), r * r])
    b = b / (np.sum(b) / np.sum(a))
    plant = ArxModel(a=a, b=b, fs_hz=FS)
    plain = dsg.design_fir(plant, 50, 32.0, 'ls', 0.01)
    tol = dsg.design_fir(plant, 50, 32.0, 'ls', 0.01, zero_tol=0.98)
    assert np.max(np.abs(np.roots(plain.denominator))) == pytest.approx(r, abs=1e-6)
    assert np.max(np.abs(np.roots(tol.denominator))) < 0.98
    assert tol.info['n_unstable_zeros'] == plain.info['n_unstable_zeros'] + 2
    for comp in (plain, tol):                        # both keep the defining constraints
        assert comp.info['passband_max_error'] <= 0.01
        assert comp.info['dc_gain_error'] < 1e-8
