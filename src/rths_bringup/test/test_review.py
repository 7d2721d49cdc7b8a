"""Review helpers: step bookkeeping and the delay estimate."""

import numpy as np

from rths_bringup.review import step_check, weighted_delay_ms


def test_step_check_counts_gaps_duplicates_and_order():
    assert step_check([0, 1, 2, 3]) == {'count': 4, 'first': 0, 'last': 3, 'gaps': 0,
                                        'duplicates': 0, 'in_order': True}
    c = step_check([0, 1, 3, 3, 2])
    assert (c['gaps'], c['duplicates'], c['in_order']) == (0, 1, False)
    c = step_check([0, 1, 5])
    assert (c['gaps'], c['in_order']) == (3, True)


def test_weighted_delay_recovers_a_pure_delay():
    fs = 1024.0
    rng = np.random.default_rng(0)
    t = np.arange(int(30 * fs)) / fs
    # narrow-band like a building response (2.7 Hz) plus broadband noise
    x = np.sin(2 * np.pi * 2.7 * t) + 0.3 * rng.standard_normal(t.size)
    lag = 14  # samples: 13.67 ms
    y = np.r_[np.zeros(lag), x[:-lag]]
    assert abs(weighted_delay_ms(x, y, fs) - 1e3 * lag / fs) < 0.05
    assert abs(weighted_delay_ms(x, x, fs)) < 1e-9
