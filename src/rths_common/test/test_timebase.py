"""Sampling rate from a printed time column, and rates compared as they are written."""

import numpy as np
import pytest

from rths_common.timebase import format_hz, infer_rate, nominal_rate, same_rate, sampling_rate_hz


def _printed(fs, n, fmt, t0=0.0):
    """Return the times of ``n`` samples at ``fs`` as printed with ``fmt``."""
    return np.array([float(fmt % x) for x in t0 + np.arange(n) / fs])


@pytest.mark.parametrize('fmt', ['%.6g', '%.7g', '%.8g', '%.9g', '%.10g', '%.6f', '%.4f'])
@pytest.mark.parametrize('fs', [1024.0, 2048.0, 4096.0, 1000.0, 1024.5])
def test_printed_times_give_the_rate_exactly(fs, fmt):
    # %.10g is the project's own CSV writer (rths_compensator.io.write_csv_columns): with it
    # 1/median(diff) gave 1024.000524 Hz, with %.6f 1023.54 Hz
    rate = infer_rate(_printed(fs, int(20 * fs), fmt))
    assert rate.fs_hz == fs and rate.snapped
    assert rate.samples == int(20 * fs)


def test_offset_start_and_the_report():
    rate = infer_rate(_printed(1024.0, 20000, '%.10g', t0=1234.5))
    assert rate.fs_hz == 1024.0
    assert str(rate).startswith('1024 Hz over 20000 samples')
    assert rate.resolution_s == pytest.approx(1e-6)


def test_a_rate_the_times_do_not_pin_keeps_the_fit():
    t = np.arange(10000) / 1024 + np.random.default_rng(1).normal(0.0, 1e-6, 10000)
    rate = infer_rate(t)                           # a jittering clock, printed in full
    assert not rate.snapped
    assert rate.fs_hz == rate.fitted_hz and same_rate(rate.fs_hz, 1024.0)
    third = infer_rate(np.arange(30000) / (1000 / 3))
    assert same_rate(third.fs_hz, 1000 / 3)


@pytest.mark.parametrize('time, match', [
    ([0.0], 'at least 2 rows'),
    ([0.0, 1.0, 1.0, 2.0], 'not increasing at row 2'),
    (np.delete(_printed(1024.0, 2000, '%.6f'), 1000), 'not uniformly sampled .* row 1000'),
    ([0.0, np.nan, 2.0], 'nan/inf'),
])
def test_bad_time_columns_are_refused_naming_the_file(time, match):
    with pytest.raises(ValueError, match=f'^run.csv: .*{match}'):
        sampling_rate_hz(time, 'run.csv')


def test_rates_compare_to_the_six_digits_they_are_printed_with():
    assert same_rate(1024.0, 1024.000524)          # both print as 1024
    assert not same_rate(1024.0, 1024.01)
    assert not same_rate(1000.0, 1024.0)
    assert nominal_rate(1024.000524) == 1024.0
    assert nominal_rate(1000 / 3) == pytest.approx(1000 / 3, rel=1e-6)
    assert format_hz(1024.0) == '1024' and format_hz(1024.000524) == '1024.000524'


def test_a_half_period_jump_is_refused_though_rows_before_it_end_in_zeros():
    # printed '%.4f': 1.9900 reads as 1.99 (coarse), 2.0050 shows the format's finer digits
    t = np.arange(500) * 0.01
    t[200:] += 0.005
    t = np.array([float(f'{x:.4f}') for x in t])
    with pytest.raises(ValueError, match='not uniformly sampled .*row 200'):
        infer_rate(t, 'uneven.dat')
