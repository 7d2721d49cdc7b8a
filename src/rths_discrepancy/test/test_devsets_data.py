"""The development data sets as the workflow's loaders read them, against each set's document.

Smoke tests of :mod:`rths_discrepancy.devsets` (and of the EMPS reader of
:mod:`rths_discrepancy.restoring`) on the real files: rates, lengths and levels as the data
set's own document states them, so a loader that drops a period, mixes columns or assumes
the wrong rate fails here before any identification runs. The data come from the data
directory (rths_common.datasets: ``$RTHS_DATA_DIR``, by default ``../shared/data`` beside
the repository), never from the repository; without them these tests skip, and fail in CI
(rths_common.testing.require_data).
"""

import numpy as np
import pytest

from rths_common.testing import require_data
from rths_discrepancy import devsets, restoring

#: Force RMS [N] of the F-16 full-grid multisines, levels 1-7 (F16Benchmark.pdf section 2.2).
F16_FORCE_RMS_N = {1: 12.4, 2: 24.6, 3: 36.8, 4: 61.4, 5: 73.6, 6: 85.7, 7: 97.8}


def _root(name):
    return str(require_data(name).parent)


def _rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


def test_f16gvt_loader_matches_the_benchmark_document():
    """F-16 GVT (Noel, Kerschen), github.com/forgi86/dynonet examples/F16GVT/data (MIT repo).

    F16Benchmark.pdf section 2.2: 400 Hz; 9 periods of 8192 points per level (the loader drops
    the first, which holds the transient); levels 1, 3, 5, 7 estimate and 2, 4, 6 test; the
    force RMS of each level as published (rounded to 0.1 N; measured force, so within 1 %);
    three accelerations as outputs.
    """
    train, test = devsets.f16(_root('f16gvt'))
    assert len(train) == 4 and len(test) == 3
    for level, rec in zip((1, 3, 5, 7, 2, 4, 6), train + test, strict=True):
        assert f'Level{level}' in rec['source']
        assert rec['fs'] == 400.0
        assert rec['u'].shape == (8 * devsets.F16_PERIOD,) and devsets.F16_PERIOD == 8192
        assert rec['y'].shape == (8 * 8192, 3) and np.all(np.isfinite(rec['y']))
        assert _rms(rec['u']) == pytest.approx(F16_FORCE_RMS_N[level], rel=0.01), level


def test_cascaded_tanks_loader_matches_the_benchmark_document():
    """Cascaded tanks (Schoukens, Mattsson, Wigren, Noel), dynonet examples/CTS/data (MIT repo).

    TanksBenchmark.pdf section 3: estimation and test multisines of 1024 points each,
    Ts = 4 s. The overflow saturates the lower tank's level (section 2): both records reach
    the sensor's 10 V ceiling and stay there for several samples.
    """
    train, test = devsets.cascaded_tanks(_root('cascaded_tanks'))
    assert len(train) == len(test) == 1
    for rec in train + test:
        assert rec['fs'] == 0.25
        assert rec['u'].shape == (1024,) and rec['y'].shape == (1024, 1)
        assert rec['y'].max() == 10.0 and np.count_nonzero(rec['y'] == 10.0) >= 3
        assert 0.0 < rec['u'].min() and rec['u'].max() < 10.0
    assert not np.array_equal(train[0]['u'], test[0]['u'])


def test_bouc_wen_loader_matches_the_benchmark_document():
    """Bouc-Wen benchmark (Noel, Schoukens; simulated), dynonet examples/BW (MIT repo).

    BoucWenBenchmark.pdf sections 4-5: 750 Hz (also the rate stored in train.h5); multisines
    of 8192 points per period at 50 N RMS, training 5 periods of one periodic input, test one
    steady-state period; the displacement of the order of millimetres (its Fig. 2).
    """
    import h5py
    root = _root('bouc_wen')
    train, test = devsets.bouc_wen(root)
    with h5py.File(require_data('bouc_wen') / 'train.h5', 'r') as h5:
        assert float(np.ravel(h5['multisine/fs'][()])[0]) == train[0]['fs'] == 750.0
    u = train[0]['u']
    assert u.shape == (5 * 8192,) and train[0]['y'].shape == (5 * 8192, 1)
    assert np.array_equal(u[:8192], u[-8192:])
    assert test[0]['fs'] == 750.0 and test[0]['u'].shape == (8192,) and test[0]['periodic']
    for rec in train + test:
        assert _rms(rec['u']) == pytest.approx(50.0, rel=1e-3)
        assert 1e-4 < np.max(np.abs(rec['y'])) < 1e-2


def test_emps_reader_matches_its_document():
    """EMPS (Janot, Gautier, Brunot), github.com/forgi86/sysid-neural-continuous (Apache-2.0).

    EMPS_Description.pdf: 1 kHz for about 25 s; force = g_tau * vir with g_tau = 35.15 N/V.
    """
    from scipy.io import loadmat
    path = require_data('emps') / 'DATA_EMPS.mat'
    data = restoring.validate(restoring.convert('emps', str(path)))
    t = data['time_s']
    assert t.size == 24841 and (t[-1] - t[0]) / (t.size - 1) == pytest.approx(1e-3, rel=1e-9)
    # the reader's rate is 1 / the median step of the stored (rounded) times: 1000.016 Hz
    assert data['fs'] == pytest.approx(1000.0, rel=1e-4)
    m = loadmat(str(path))
    assert float(m['gtau'].ravel()[0]) == pytest.approx(35.15, abs=0.005)
    np.testing.assert_allclose(data['force_N'], 35.15 * m['vir'].ravel(), rtol=2e-4)
