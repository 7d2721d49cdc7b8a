"""The io scenario's short-horizon measure, plateaus under noise and held-out confirmation.

Records from :mod:`rths_discrepancy.unseen`'s shaker tests (DOP853) with parameters of
development seeds (issue 25: 155 for the near-chaotic Duffing, 111/124 for the noisy
clip); the judged seeds are never used here.
"""

import numpy as np
from scipy import signal

from rths_compensator.identification import ArxModel
from rths_discrepancy import iodisc, linear, unseen


def _record(u, y, fs, name='r'):
    return {'u': u, 'y': np.column_stack([y]), 'fs': fs, 'source': name, 'outputs': ['y'],
            'input': 'u'}


def _floor(rec, clean):
    k = int(iodisc.TRAIN_FRACTION * rec['u'].size)
    y = rec['y'][k:, 0]
    return float(np.sqrt(np.mean((y - clean[k:]) ** 2)) / np.std(y))


def test_a_re_initialised_linear_model_predicts_its_own_output_exactly():
    # y of an ARX model itself, from an initial state the model does not know: the free
    # run (from rest) carries the transient, each short window starts from the measured
    # lags and is exact; a horizon longer than the record is the free run
    fs = 100.0
    rng = np.random.default_rng(3)
    u = signal.lfilter([1.0], [1, -0.7], rng.standard_normal(3000))
    arx = ArxModel(a=np.array([1.0, -1.6, 0.8]), b=np.array([0.3, 0.1]), d=1, fs_hz=fs)
    lm = linear.LinearModel(arx, 1, fs, 0.0, 0.0, 'arx')
    y = signal.lfilter(arx.num, arx.a, u, zi=[5.0, -3.0])[0]
    short = iodisc.shoot_linear(lm, u, y, 20, 0)
    free = iodisc.shoot_linear(lm, u, y, 10 ** 6, 0)
    np.testing.assert_allclose(free, lm.simulate(u), atol=1e-9)
    np.testing.assert_allclose(short[20:], y[20:], atol=1e-9)
    assert np.max(np.abs(free - y)[20:]) > 0.1


def test_a_near_chaotic_duffing_is_named_by_the_short_horizon_comparison():
    # development seed 155's io Duffing: cubic force at the rms 2.2x the linear one, 2.6 %
    # damping; every free run misses (the baseline 0.83 held out, named none before the
    # short-horizon measure): the measure switches, the cubic law refitted by multiple
    # shooting closes the gap
    case = {'name': 'duffing', 'scenario': 'io', 'effect': 'duffing', 'fs': 1000.0, 'n': 4000,
            'fn_hz': 28.2439658925756, 'excitation': 'random', 'zeta': 0.026192900402195653,
            'units': 'volts', 'noise': 0.004657107785750123, 'size': 0.7333645016329537,
            'offset': False, 'seed': 944425407}
    rec, clean = unseen.io_case(case)
    res = iodisc.run([rec], plots=False)
    p = res['per_output']['y']
    m = p['error_measure']
    assert m['kind'].startswith('short-horizon') and m['horizon_samples'] > 0
    assert m['training_free_run_nrmse_baseline'] > iodisc.FREE_RUN_POOR
    assert res['effect'] == 'cubic_stiffness'
    floor = _floor(rec, clean)
    b, a = p['nrmse_baseline'], p['nrmse_after']
    assert (b ** 2 - a ** 2) >= 0.5 * (b ** 2 - floor ** 2)
    assert p['free_run_nrmse_baseline'] > 0.5          # what the free run would have said


def test_a_noisy_plateau_is_read_on_the_running_median():
    # development seed 124's clip: 1.3 % output noise lifts the maximum 0.7 % of the span
    # above the limit with few samples near it; the raw reading finds no plateau
    case = {'name': 'clip', 'scenario': 'io', 'effect': 'output_clipping', 'fs': 1234.5,
            'n': 10000, 'fn_hz': 59.790587006565666, 'excitation': 'random',
            'zeta': 0.05668248785383968, 'units': 'volts', 'noise': 0.013251155519490979,
            'size': 0.7522475451314519, 'offset': True, 'seed': 1369508843}
    rec, clean = unseen.io_case(case)
    k = int(iodisc.TRAIN_FRACTION * rec['u'].size)
    y = rec['y'][:k, 0]
    assert iodisc._plateau(y, True) is None
    (hi, lo), _ = iodisc.plateaus(y)
    lim = float(np.max(clean[:k]))
    assert hi is not None and lo is None
    assert abs(hi - lim) < 0.003 * np.ptp(y)


def test_a_miss_the_training_part_does_not_show_is_unexplained_not_a_name():
    # a linear shaker record whose input grows in its later part, where the output clips;
    # the training part (the first 60 %) never reaches the limit: no block can be told
    # from it, and the answer is 'unexplained', not a wrong name
    fs = 500.0
    n = 8000
    rng = np.random.default_rng(21)
    u = signal.sosfilt(signal.butter(4, 40.0, fs=fs, output='sos'), rng.standard_normal(n))
    u[int(0.65 * n):] *= 2.5
    num, den = signal.cont2discrete(([(2 * np.pi * 12) ** 2],
                                     [1, 2 * 0.05 * 2 * np.pi * 12, (2 * np.pi * 12) ** 2]),
                                    1 / fs, method='zoh')[:2]
    y = signal.lfilter(num.ravel(), den, u)
    lim = 1.2 * np.max(np.abs(y[:int(0.6 * n)]))
    y = np.minimum(y, lim) + 0.003 * np.std(y) * rng.standard_normal(n)
    res = iodisc.run([_record(u, y, fs)], plots=False)
    assert res['effect'] == 'unexplained'
    p = res['per_output']['y']
    assert p['nrmse_after'] == p['nrmse_baseline']
    assert p['limit_only_in_heldout_part']
    assert iodisc.plateaus(y[:int(0.6 * n)])[0] == [None, None]
