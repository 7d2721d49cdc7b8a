"""Ground motions: gmspy records, AT2 reader, resampling, baseline correction."""

import numpy as np
import pytest

from rths_numerical import ground_motion as gm


@pytest.mark.parametrize('name', ['kobe', 'northridge', 'imperial_valley'])
def test_gmspy_records_units(name):
    """Gmspy files: 0.01 s step, acceleration in g -> m/s^2 (peaks between 0.1 g and 1.5 g)."""
    dt, acc = gm.load_record(name)
    assert dt == pytest.approx(0.01)
    assert 0.1 * gm.G < np.max(np.abs(acc)) < 1.5 * gm.G
    assert acc.size > 3000


def test_at2_reader(tmp_path):
    """PEER AT2: 4 header lines, NPTS/DT, values in g."""
    vals = np.array([0.0, 0.01, -0.02, 0.03, 0.0, -0.01, 0.005])
    text = 'PEER NGA STRONG MOTION DATABASE RECORD\nTEST 1999, STATION, 090\n' \
           'ACCELERATION TIME SERIES IN UNITS OF G\nNPTS=    7, DT=   .0050 SEC\n'
    text += '  '.join(f'{v:.7E}' for v in vals[:5]) + '\n' + '  '.join(
        f'{v:.7E}' for v in vals[5:]) + '\n'
    path = tmp_path / 'rec.AT2'
    path.write_text(text)
    dt, acc = gm.load_record(str(path))
    assert dt == pytest.approx(0.005)
    assert np.allclose(acc, vals * gm.G)


def test_unknown_record_message():
    """Unknown name: the message lists the valid names."""
    with pytest.raises(ValueError, match='kobe'):
        gm.load_record('elcentro_missing')


def test_resample_preserves_sine():
    """A 2 Hz sine at 100 Hz resampled to 1024 Hz keeps amplitude and phase."""
    dt = 0.01
    t = np.arange(1000) * dt
    y = gm.resample(np.sin(2 * np.pi * 2 * t) * np.hanning(1000), dt, 1024.0)
    t2 = np.arange(y.size) / 1024.0
    ref = np.sin(2 * np.pi * 2 * t2) * np.interp(t2, t, np.hanning(1000))
    assert y.size == 10240
    assert np.max(np.abs(y - ref)[500:-500]) < 1e-2


def test_baseline_correction_consistent():
    """Corrected a, v, u are consistent (trapezoidal rule) and the ground ends near rest."""
    dt, acc = gm.load_record('northridge')
    a, v, u = gm.baseline_correct(acc, dt)
    v2, u2 = gm.integrate(a, dt)
    assert np.allclose(v, v2) and np.allclose(u, u2)
    _, u_raw = gm.integrate(acc - acc.mean(), dt)
    assert abs(u[-1]) < 0.05 * np.max(np.abs(u)) or abs(u[-1]) < 0.1 * abs(u_raw[-1])
