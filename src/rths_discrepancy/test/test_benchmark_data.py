"""The discrepancy development data sets read from their original files (benchmark_data).

Smoke tests of the loaders on the real files: shapes, rates and levels against each data
set's own document. The data come from the data directory (rths_common.datasets;
``$RTHS_DATA_DIR``, by default ``../shared/data`` beside the repository), not from the
repository; without them these tests skip, and fail in CI (rths_common.testing).
"""

import numpy as np
import pytest

from rths_common.testing import require_data
from rths_discrepancy import benchmark_data as bd

#: Force RMS [N] of each F-16 record, F16Benchmark.pdf sections 2.2 (full-grid multisines,
#: levels 1-7) and 2.3 (special odd multisines, levels 1-3).
F16_FORCE_RMS_N = {'FullMSine_Level1': 12.4, 'FullMSine_Level2_Validation': 24.6,
                   'FullMSine_Level3': 36.8, 'FullMSine_Level4_Validation': 61.4,
                   'FullMSine_Level5': 73.6, 'FullMSine_Level6_Validation': 85.7,
                   'FullMSine_Level7': 97.8, 'SpecialOddMSine_Level1_Validation': 12.2,
                   'SpecialOddMSine_Level2_Validation': 49.0,
                   'SpecialOddMSine_Level3_Validation': 97.1}


def _rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


def test_f16gvt_records_match_the_benchmark_document():
    """F-16 GVT (Noel, Kerschen), github.com/forgi86/dynonet examples/F16GVT/data (MIT repo).

    F16Benchmark.pdf: 400 Hz; full-grid multisines 9 periods of 8192 points, special odd
    multisines 3 periods of 16384 points; the force RMS of each level as published (the
    document rounds to 0.1 N; measured force, so within 1 %).
    """
    folder = require_data('f16gvt')
    for name, rms in F16_FORCE_RMS_N.items():
        rec = bd.f16gvt(name, str(folder))
        assert rec.fs_hz == 400.0
        assert list(rec.columns) == list(bd.F16_COLUMNS)
        periods, period = (9, 8192) if name.startswith('Full') else (3, 16384)
        assert rec.n_samples == periods * period, name
        assert all(c.shape == (periods * period,) and np.all(np.isfinite(c))
                   for c in rec.columns.values())
        assert _rms(rec.columns['Force']) == pytest.approx(rms, rel=0.01), name
    with pytest.raises(ValueError, match='FullMSine_Level1'):
        bd.f16gvt('Level9', str(folder))


def test_cascaded_tanks_match_the_benchmark_document():
    """Cascaded tanks (Schoukens, Mattsson, Wigren, Noel), dynonet examples/CTS/data (MIT repo).

    TanksBenchmark.pdf section 3: estimation and test multisines of 1024 points each, Ts = 4 s;
    the overflow saturates the lower tank's level, visible in the outputs (both records reach
    the sensor's 10 V ceiling and stay at it for several samples).
    """
    folder = require_data('cascaded_tanks')
    recs = bd.cascaded_tanks(str(folder))
    assert set(recs) == {'estimation', 'test'}
    for rec in recs.values():
        assert rec.fs_hz == pytest.approx(0.25) and rec.n_samples == 1024
        assert set(rec.columns) == {'u', 'y'}
        y = rec.columns['y']
        assert y.max() == 10.0 and np.count_nonzero(y == 10.0) >= 3
        assert 0.0 < rec.columns['u'].min() and rec.columns['u'].max() < 10.0
    assert not np.array_equal(recs['estimation'].columns['u'], recs['test'].columns['u'])


def test_bouc_wen_records_match_the_benchmark_document():
    """Bouc-Wen benchmark (Noel, Schoukens; simulated), dynonet examples/BW (MIT repo).

    BoucWenBenchmark.pdf sections 4-5: 750 Hz; multisines of 8192 points per period at 50 N
    RMS (training: 5 periods, test: one steady-state period); the sine-sweep test record at
    40 N amplitude, 20-50 Hz at 10 Hz/min (153000 points, 204 s). The HDF5 test records are
    the benchmark's own .mat test files.
    """
    folder = require_data('bouc_wen')
    recs = bd.bouc_wen(str(folder))
    assert set(recs) == {'train_multisine', 'test_multisine', 'test_sinesweep'}
    assert all(r.fs_hz == bd.BOUC_WEN_FS_HZ == 750.0 for r in recs.values())
    train = recs['train_multisine']
    assert train.n_samples == 5 * 8192
    u = train.columns['u'].reshape(5, 8192)
    assert np.array_equal(u[0], u[-1])                               # one periodic input
    assert _rms(train.columns['u']) == pytest.approx(50.0, rel=1e-3)
    assert recs['test_multisine'].n_samples == 8192
    assert _rms(recs['test_multisine'].columns['u']) == pytest.approx(50.0, rel=1e-3)
    sweep = recs['test_sinesweep']
    assert sweep.n_samples == 153000
    assert np.max(np.abs(sweep.columns['u'])) == pytest.approx(40.0, rel=1e-6)
    assert 0.0 < np.max(np.abs(train.columns['y'])) < 0.01           # metres: millimetre scale
    for kind in ('multisine', 'sinesweep'):
        mat = bd.bouc_wen_mat(kind, str(folder))
        for col in ('u', 'y'):
            np.testing.assert_array_equal(mat.columns[col], recs[f'test_{kind}'].columns[col])


def test_emps_record_matches_its_document():
    """EMPS (Janot, Gautier, Brunot), github.com/forgi86/sysid-neural-continuous (Apache-2.0).

    EMPS_Description.pdf: 1 kHz, about 25 s, the drive gain g_tau = 35.15 N/V.
    """
    from scipy.io import loadmat
    folder = require_data('emps')
    for name in ('DATA_EMPS.mat', 'DATA_EMPS_PULSES.mat'):
        m = loadmat(str(folder / name))
        t = m['t'].ravel()
        assert np.median(np.diff(t)) == pytest.approx(1e-3, rel=1e-3)
        assert t[-1] == pytest.approx(24.84) and m['qm'].size == m['vir'].size == t.size
        assert float(m['gtau'].ravel()[0]) == pytest.approx(35.15, abs=0.005)


def test_a_missing_file_names_the_path(tmp_path):
    with pytest.raises(OSError, match='dataBenchmark.csv: no such file'):
        bd.cascaded_tanks(str(tmp_path))
    with pytest.raises(OSError, match='train.h5: no such file'):
        bd.bouc_wen(str(tmp_path))
