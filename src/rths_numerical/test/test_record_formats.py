"""Every record format reads every sample of its file exactly: no row dropped, no shift."""

import numpy as np
import pytest

from rths_numerical import ground_motion as gm

G = 9.80665
RNG = np.random.default_rng(5)
ACCEL = np.round(RNG.normal(0.0, 0.05, 997), 6)      # in g, six decimals as written
DT = 0.005


def write(path, text):
    path.write_text(text)
    return path


def rows(sep, unit_factor=1.0, t0=0.0):
    return ''.join(f'{t0 + k * DT:.3f}{sep}{a * unit_factor:.6f}\n' for k, a in enumerate(ACCEL))


def as_written(unit_factor):
    """Return the accelerations [m/s^2] as the file holds them (six decimals in its unit)."""
    return np.array([float(f'{a * unit_factor:.6f}') for a in ACCEL]) * (G / unit_factor)


def check_every_sample(motion, unit_factor=1.0, t0=0.0):
    """Compare every sample read with the file: count, order, value, time step, first time."""
    assert motion.accel.size == ACCEL.size
    np.testing.assert_allclose(motion.accel, as_written(unit_factor), rtol=1e-15, atol=0)
    assert motion.dt == pytest.approx(DT, rel=1e-12) and motion.t0 == pytest.approx(t0)


def test_text_csv_with_the_unit_in_the_header_name(tmp_path):
    path = write(tmp_path / 'r.csv', 'time_s,accel_g\n' + rows(','))
    motion = gm.read_record(path)
    assert motion.fmt == 'text' and motion.units == 'g'
    check_every_sample(motion)


def test_text_whitespace_with_one_header_line_loses_no_row(tmp_path):
    """The file of the issue: one header line, spaces; every row read (no 20 ms shift)."""
    path = write(tmp_path / 'r.dat', 'time [s]   accel [m/s^2]\n' + rows('   ', G))
    check_every_sample(gm.read_record(path), G)


def test_text_with_a_preamble_and_cm_s2_from_the_option(tmp_path):
    text = 'Station XYZ\nFiltered 0.1-25 Hz\n\ntime\tacc\n' + rows('\t', G * 100, t0=0.02)
    path = write(tmp_path / 'r.txt', text)
    check_every_sample(gm.read_record(path, units='cm/s^2'), G * 100, t0=0.02)
    check_every_sample(gm.read_record(path, units='gal'), G * 100, t0=0.02)


def test_series_with_dt(tmp_path):
    path = write(tmp_path / 's.txt', 'accel [g]\n' + ''.join(f'{a:.6f}\n' for a in ACCEL))
    motion = gm.read_record(path, dt_s=DT)
    assert motion.fmt == 'series'
    check_every_sample(motion)
    with pytest.raises(ValueError, match='needs its time step: give --record-dt'):
        gm.read_record(path)


def test_peer_at2(tmp_path):
    vals = ' '.join(f'{a:.6E}' for a in ACCEL)
    path = write(tmp_path / 'r.AT2', 'PEER\nX\nUNITS OF G\n'
                 f'NPTS=  {ACCEL.size}, DT=  {DT:.4f} SEC\n{vals}\n')
    motion = gm.read_record(path)
    assert motion.fmt == 'at2'
    check_every_sample(motion)
    with pytest.raises(ValueError, match='is in g'):
        gm.read_record(path, units='gal')


def test_a_unit_named_nowhere_or_twice_differently_is_refused(tmp_path):
    bare = write(tmp_path / 'r.csv', 'time,accel\n' + rows(','))
    with pytest.raises(ValueError, match='acceleration unit is not named.*--record-units'):
        gm.read_record(bare)
    named = write(tmp_path / 'n.csv', 'time [s],accel [g]\n' + rows(','))
    with pytest.raises(ValueError, match='header says the acceleration is in g but '
                                         '--record-units says gal'):
        gm.read_record(named, units='gal')
    with pytest.raises(ValueError, match="unit 'furlong' is not known"):
        gm.read_record(bare, units='furlong')


def test_a_dt_that_contradicts_the_time_column_is_refused(tmp_path):
    path = write(tmp_path / 'r.csv', 'time_s,accel_g\n' + rows(','))
    with pytest.raises(ValueError, match='the time column steps 0.005 s but --record-dt says'):
        gm.read_record(path, dt_s=0.01)


def test_the_summary_reports_first_last_duration_rate_and_peak(tmp_path):
    motion = gm.read_record(write(tmp_path / 'r.csv', 'time_s,accel_g\n' + rows(',')))
    s = motion.summary()
    i = int(np.argmax(np.abs(ACCEL)))
    assert s['samples'] == ACCEL.size and s['fs_hz'] == pytest.approx(200.0)
    assert s['duration_s'] == pytest.approx((ACCEL.size - 1) * DT)
    assert s['first_m_s2'] == ACCEL[0] * G and s['last_m_s2'] == ACCEL[-1] * G
    assert s['peak_m_s2'] == pytest.approx(abs(ACCEL[i]) * G) and s['peak_time_s'] == i * DT
    assert 'peak' in motion.describe() and '200 Hz' in motion.describe()


def test_processing_is_stated_and_each_step_switches_off(tmp_path):
    motion = gm.read_record(write(tmp_path / 'r.csv', 'time_s,accel_g\n' + rows(',')))
    used, _ = gm.prepare(motion, 1000.0, 1.0)
    assert used.processing[1] == 'resampled 200 -> 1000 Hz (band-limited FFT)'
    assert used.processing[2].startswith('mean removed')
    assert used.processing[3].startswith('baseline corrected')
    off = gm.Processing(resample=True, remove_mean=False, baseline=False)
    raw, _ = gm.prepare(motion, 1000.0, 1.0, processing=off)
    assert raw.processing[2:] == ('mean kept (mean removal off)', 'no baseline correction (off)')
    # the record's samples fall on every 5th loop step: band-limited resampling passes
    # through them (away from the ends, where the zero padding's wrap-around acts): no shift
    np.testing.assert_allclose(raw.accel[::5][:ACCEL.size][100:-100], motion.accel[100:-100],
                               atol=1e-9)
    with pytest.raises(ValueError, match='resampling is off'):
        gm.prepare(motion, 1000.0, 1.0, processing=gm.Processing(resample=False))
    same, _ = gm.prepare(motion, 200.0, 2.0, processing=gm.Processing(False, False, False))
    np.testing.assert_array_equal(same.accel, 2.0 * motion.accel)
