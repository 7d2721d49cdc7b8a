"""Table 1 models, Appendix I threshold, ARX identification and selection (eq. 26-40)."""

import numpy as np
import pytest
from scipy import signal

from rths_compensator.identification import (
    ArxModel,
    arx_grid,
    factor_zeros,
    fit_arx,
    load_plant,
    model_from_grid,
    save_plant,
)
from rths_compensator.plants import (
    continuous_actuator,
    discrete_actuator,
    unstable_zero_threshold_hz,
)


@pytest.mark.parametrize('kind', ['3pole', '4pole'])
def test_discrete_actuator_unit_dc_gain_and_convention(kind):
    b, a = discrete_actuator(kind, 1024.0)
    assert abs(np.sum(b) / np.sum(a) - 1.0) < 1e-9
    # No pure one-sample delay in the project convention: b[0] carries the first response.
    assert b[0] > 0
    num, den = continuous_actuator(kind)
    step_ct = signal.step((num, den), T=np.arange(0, 51) / 1024.0)[1][1:]
    step_dt = signal.lfilter(b, a, np.ones(50))
    # measurement k is read at the END of sample k: y_k = continuous response at (k+1) dt
    np.testing.assert_allclose(step_dt, step_ct, atol=1e-9)


@pytest.mark.parametrize('kind, seed_hz', [('3pole', 41.0), ('4pole', 42.0)])
def test_unstable_zero_threshold_matches_appendix_one(kind, seed_hz):
    """Appendix I / Figure I.1: ~41 Hz (3-pole), ~42 Hz (4-pole); we accept +-1 Hz."""
    fs = unstable_zero_threshold_hz(kind)
    assert abs(fs - seed_hz) <= 1.0
    b_lo, _ = discrete_actuator(kind, fs - 0.5)
    b_hi, _ = discrete_actuator(kind, fs + 0.5)
    assert np.max(np.abs(np.roots(b_lo))) < 1.0 < np.max(np.abs(np.roots(b_hi)))


def test_factor_zeros_splits_stable_and_unstable():
    b = 2.0 * np.poly([0.5, -3.0, 1.664])
    b_plus, b_minus = factor_zeros(b)
    np.testing.assert_allclose(np.convolve(b_plus, b_minus), b, atol=1e-12)
    assert np.all(np.abs(np.roots(b_plus)) < 1)
    assert np.all(np.abs(np.roots(b_minus)) >= 1) and b_minus.size == 3
    bp, bm = factor_zeros([3.0])
    assert bp.tolist() == [1.0] and bm.tolist() == [3.0]


def _simulate_records(a, b, d, n_rec, n, rng, noise=0.0):
    """Return records of the ARX system eq. 26 with white equation error e of std ``noise``."""
    recs = []
    for _ in range(n_rec):
        u = rng.standard_normal(n)
        e = noise * rng.standard_normal(n)
        y = signal.lfilter(np.r_[np.zeros(d), b], a, u) + signal.lfilter([1.0], a, e)
        recs.append((u, y))
    return recs


def test_fit_arx_recovers_known_system():
    rng = np.random.default_rng(0)
    a, b = np.array([1.0, -1.5, 0.7]), np.array([0.5, 0.25, -0.1])
    model = fit_arx(_simulate_records(a, b, 1, 3, 2000, rng), 2, 3, d=1)
    np.testing.assert_allclose(model.a, a, atol=1e-9)
    np.testing.assert_allclose(model.b, b, atol=1e-9)


def test_grid_selects_true_order_and_dead_time():
    """On a small grid, BIC over several validation records picks the true (na, nb, d)."""
    rng = np.random.default_rng(1)
    a, b, d = np.array([1.0, -1.2, 0.5]), np.array([0.3, 0.2]), 1
    train = _simulate_records(a, b, d, 2, 3000, rng, noise=0.01)
    val = _simulate_records(a, b, d, 6, 2000, rng, noise=0.01)
    for error in ('prediction', 'simulation'):
        grid = arx_grid(train, val, range(1, 5), range(1, 5), range(0, 3), fs_hz=100.0,
                        error=error)
        model = model_from_grid(grid, 'bic')
        assert (model.na, model.nb, model.d) == (2, 2, 1), error
        assert sum(grid['histogram']['bic'].values()) == 6
        np.testing.assert_allclose(model.a, a, atol=0.02)


def test_prediction_scores_from_gram_equal_direct_computation():
    rng = np.random.default_rng(2)
    a, b = np.array([1.0, -0.9]), np.array([1.0, 0.5])
    train = _simulate_records(a, b, 0, 1, 1500, rng, noise=0.05)
    val = _simulate_records(a, b, 0, 2, 800, rng, noise=0.05)
    grid = arx_grid(train, val, range(1, 4), range(1, 4), (0,), error='prediction')
    k = [tuple(o) for o in grid['orders']].index((2, 3, 0))
    theta = grid['thetas'][k]
    u, y = val[0]
    t0 = 3  # first row of the regression: largest lag of the grid (na_max = 3)
    pred = np.array([-theta[0] * y[t - 1] - theta[1] * y[t - 2] + theta[2] * u[t]
                     + theta[3] * u[t - 1] + theta[4] * u[t - 2] for t in range(t0, y.size)])
    mse = np.mean((y[t0:] - pred) ** 2)
    assert grid['scores']['mse'][0, k] == pytest.approx(mse, rel=1e-8)


def test_plant_yaml_roundtrip(tmp_path):
    model = ArxModel(a=[1.0, -0.5, 0.1], b=[0.2, 0.4], d=0, fs_hz=1024.0)
    path = tmp_path / 'plant.yaml'
    save_plant(path, model, {'criterion': 'bic', 'counts': np.array([1, 2])})
    back = load_plant(path)
    np.testing.assert_array_equal(back.a, model.a)
    np.testing.assert_array_equal(back.b, model.b)
    assert back.fs_hz == 1024.0 and back.d == 0
    u = np.random.default_rng(0).standard_normal(100)
    np.testing.assert_allclose(back.simulate(u), signal.lfilter(model.b, model.a, u))
    path.write_text('kind: arx\nfs_hz: 1024.0\nb: [1.0]\n')
    with pytest.raises(ValueError, match='field a'):
        load_plant(path)


def test_arx_grid_warmup_scores_only_the_samples_after_it():
    # a lightly damped plant: the validation record is the whole record, scored from
    # sample k on (simulated through the samples before it, as the later part of a
    # record is); the score is the mean square error of the tail only
    rng = np.random.default_rng(3)
    u = rng.standard_normal(3000)
    y = signal.lfilter([0.0, 0.02], [1.0, -1.96, 0.98], u)
    k = 2000
    g = arx_grid([(u[:k], y[:k])], [(u, y)], range(1, 3), range(1, 3), (0, 1), fs_hz=100.0,
                 warmup=k)
    for i, (na, _nb, d) in enumerate(g['orders']):
        th = g['thetas'][i]
        sim = signal.lfilter(np.r_[np.zeros(d), th[na:]], np.r_[1.0, th[:na]], u)
        tail = np.mean((y - sim)[k:] ** 2)
        assert g['scores']['mse'][0, i] == pytest.approx(tail, rel=1e-9, abs=1e-30)
    with pytest.raises(ValueError, match='warmup'):
        arx_grid([(u[:k], y[:k])], [(u, y)], range(1, 2), range(1, 2), (0,), warmup=[k, k])
