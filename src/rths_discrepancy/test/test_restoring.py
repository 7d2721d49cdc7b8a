"""Tests of the restoring-force scenario (issue 15) on synthetic measured-specimen records.

The synthetic records are a displacement path (three sines) and the force of
``m a + c v + k x`` plus a known effect, with 0.5 % white noise on the force.
The real records (EMPS, MR damper) come from the data directory (rths_common.datasets:
``$RTHS_DATA_DIR``, by default ``../shared/data`` beside the repository), not from the
repository; without them those tests skip, and fail in CI (rths_common.testing).
"""

import json
import os

import numpy as np
import pytest

from rths_common.testing import require_data
from rths_discrepancy import effects as fx
from rths_discrepancy import restoring

FS = 200.0
M, C, K = 20.0, 300.0, 2.0e4


def _record(effects, seed=0, duration_s=24.0, noise=0.005):
    rng = np.random.default_rng(seed)
    t = np.arange(int(duration_s * FS)) / FS
    x = np.zeros_like(t)
    v = np.zeros_like(t)
    a = np.zeros_like(t)
    for f, amp in ((0.4, 0.010), (1.1, 0.006), (2.3, 0.003)):
        w, ph = 2 * np.pi * f, rng.uniform(0, 2 * np.pi)
        x += amp * np.sin(w * t + ph)
        v += amp * w * np.cos(w * t + ph)
        a -= amp * w * w * np.sin(w * t + ph)
    force = M * a + C * v + K * x
    if 'coulomb_friction' in effects:
        force += effects['coulomb_friction'] * np.tanh(v / 1e-3)
    if 'force_offset' in effects:
        force += effects['force_offset']
    if 'hysteresis' in effects:
        alpha, x_y = effects['hysteresis']
        force += alpha * fx.bouc_wen(x, x_y)
    force += noise * np.std(force) * rng.standard_normal(t.size)
    return {'time_s': t, 'displacement_m': x, 'force_N': force}


def _run(effects, **kw):
    return restoring.run(restoring.validate(_record(effects, **kw)), plots=False)


def test_linear_specimen_is_none_and_its_model_is_fitted():
    res = _run({})
    assert res['effect'] == 'none'
    mp = res['model_parameters']
    assert mp['m'] == pytest.approx(M, rel=0.05)
    assert mp['c'] == pytest.approx(C, rel=0.05)
    assert mp['k'] == pytest.approx(K, rel=0.02)
    assert abs(res['alignment_samples']) <= restoring.ALIGN_SAMPLES


def test_coulomb_friction_is_named_and_recovered_in_any_units():
    res = _run({'coulomb_friction': 40.0})
    assert res['effect'] == 'coulomb_friction'
    assert res['parameters']['coulomb_friction']['F_c'] == pytest.approx(40.0, rel=0.1)
    assert res['nrmse_after'] < 0.3 * res['nrmse_before']
    # the same record in volts and millimetres: the same answer, the amplitude scaled
    data = _record({'coulomb_friction': 40.0})
    data = {'time_s': data['time_s'], 'displacement_m': 1e3 * data['displacement_m'],
            'force_N': 1e-3 * data['force_N']}
    res_v = restoring.run(restoring.validate(data), plots=False)
    assert res_v['effect'] == 'coulomb_friction'
    assert res_v['parameters']['coulomb_friction']['F_c'] == pytest.approx(0.040, rel=0.1)


def test_bouc_wen_hysteresis_is_named():
    res = _run({'hysteresis': (60.0, 0.002)}, seed=1)
    assert res['effect'] == 'hysteresis'
    par = res['parameters']['hysteresis']
    assert par['alpha'] == pytest.approx(60.0, rel=0.15)
    assert par['x_y'] == pytest.approx(0.002, rel=0.25)
    assert res['nrmse_after'] < 0.2 * res['nrmse_before']


def test_load_cell_offset_is_named():
    res = _run({'force_offset': 30.0}, seed=2)
    assert res['effect'] == 'force_offset'
    assert res['parameters']['force_offset']['F_0'] == pytest.approx(30.0, rel=0.05)


def test_sliding_friction_with_offset_names_both_and_gives_the_asymmetric_reading():
    # while the specimen slides, Coulomb friction + offset and asymmetric friction are the
    # same two force levels: the record cannot tell them apart, the elementary effects are named
    res = _run({'coulomb_friction': 40.0, 'force_offset': 30.0}, seed=3)
    assert res['effect'] == 'coulomb_friction+force_offset'
    assert res['equivalence']['told_apart'] is False
    assert res['parameters']['force_offset']['F_0'] == pytest.approx(30.0, rel=0.05)
    levels = res['equivalent_reading']['asymmetric_friction']
    assert levels['F_p'] == pytest.approx(70.0, rel=0.05)
    assert levels['F_n'] == pytest.approx(10.0, rel=0.1)


def test_asymmetric_friction_is_named_when_the_specimen_rests():
    # with rests, the two readings differ (no friction force at rest, but an offset would
    # remain): the record tells them apart and asymmetric friction is named
    rng = np.random.default_rng(4)
    t = np.arange(int(24 * FS)) / FS
    moving = np.clip(1.5 * np.sin(2 * np.pi * t / 4.0) + 0.5, 0, 1) ** 2
    path = 0.010 * np.sin(2 * np.pi * 0.7 * t + 1.0) + 0.004 * np.sin(2 * np.pi * 1.9 * t)
    x = np.cumsum(moving * np.gradient(path))
    v = np.gradient(x, 1 / FS)
    th = np.tanh(v / 1e-3)
    force = (M * np.gradient(v, 1 / FS) + C * v + K * x + 50.0 * np.maximum(th, 0)
             + 20.0 * np.minimum(th, 0))
    force += 0.005 * np.std(force) * rng.standard_normal(t.size)
    res = restoring.run(restoring.validate({'time_s': t, 'displacement_m': x, 'force_N': force}),
                        plots=False)
    assert res['effect'] == 'asymmetric_friction'
    assert res['equivalence']['told_apart'] is True
    assert res['parameters']['asymmetric_friction']['F_p'] == pytest.approx(50.0, rel=0.05)
    assert res['parameters']['asymmetric_friction']['F_n'] == pytest.approx(20.0, rel=0.05)
    assert res['equivalent_reading']['force_offset']['F_0'] == pytest.approx(15.0, rel=0.1)


def test_bouc_wen_variable_stays_bounded_and_unloads_linearly():
    x = np.concatenate([np.linspace(0, 1, 101), np.linspace(1, 0.95, 6)])
    z = fx.bouc_wen(x, 0.1)
    assert z[100] == pytest.approx(1.0 - np.exp(-10.0), rel=1e-9)   # loading: 1 - e^(-x/x_y)
    assert z[-1] == pytest.approx(z[100] - 0.5, abs=1e-9)            # unloading: dz = dx / x_y
    assert np.all(np.abs(z) <= 1.0)


def test_csv_contract_and_errors(tmp_path):
    from rths_bringup.cli import main
    data = _record({'coulomb_friction': 40.0}, duration_s=12.0)
    path = tmp_path / 'specimen.csv'
    with open(path, 'w') as fh:
        fh.write('time_s,displacement_m,force_N,comment\n')
        for row in zip(data['time_s'], data['displacement_m'], data['force_N'], strict=True):
            fh.write('%.9g,%.9g,%.9g,x\n' % row)
    out = tmp_path / 'out'
    assert main(['discrepancy', '--scenario', 'restoring-force', '--measured', str(path),
                 '--out', str(out)]) == 0
    res = json.loads((out / 'result.json').read_text())
    for key in ('effect', 'parameters', 'nrmse_before', 'nrmse_after', 'gap_closed',
                'alignment_s'):
        assert key in res
    assert res['effect'] == 'coulomb_friction'
    assert os.path.getsize(out / 'restoring_force.png') > 1000
    report = (out / 'report.md').read_text()
    assert 'restoring_force.png' in report
    sd = res['smoothing_differentiator']      # the states' cut-off and who chose it
    assert f"cut off at {sd['cutoff_hz']:.4g} Hz" in report
    assert sd['cutoff_candidates'][0] in report
    bad = dict(data)
    bad['time_s'] = data['time_s'].copy()
    bad['time_s'][50:] += 0.3 / FS
    with pytest.raises(ValueError, match='not uniformly sampled'):
        restoring.validate(bad)
    with pytest.raises(ValueError, match='missing column.*force_N'):
        restoring.validate({'time_s': data['time_s'], 'displacement_m': data['time_s']})
    assert main(['discrepancy', '--scenario', 'restoring-force', '--measured', str(path),
                 '--model', 'm.yaml', '--out', str(tmp_path / 'o2')]) == 2


def test_real_mr_damper_short_record():
    """MR damper, 2 mm at 5 Hz and 1 A: held-out NRMSE <= 8 % and the gap halved at least.

    Data: the measured sinusoid test 2mm5Hz1A.txt of github.com/DanielMaurelE/
    vRTHS_AMBC_MRdamper (MIT, (c) 2022 mequiroz). The record has no published fit of this
    workflow's kind: the figure is the project's target for a named effect on a measured
    MR damper (8 %), well above the measurement noise; the Spencer et al. (1997) model fit
    to all 30 tests is tested in rths_numerical's test_mr_damper.
    """
    path = require_data('mr_damper') / '2mm5Hz1A.txt'
    res = restoring.run(restoring.validate(restoring.convert('mr-damper', path)), plots=False)
    assert res['effect'] not in ('none', 'unexplained')
    assert res['nrmse_after'] <= 0.08
    assert res['nrmse_after'] < 0.5 * res['nrmse_before']


def test_real_emps_names_friction_with_offset():
    """EMPS: friction with force_offset named, NRMSE <= 5 %, parameters within 10 % of published.

    Data: the measured estimation record DATA_EMPS.mat of the EMPS benchmark (Janot, Gautier,
    Brunot), github.com/forgi86/sysid-neural-continuous examples/EMPS/data (Apache-2.0).
    Published figure: the IDIM-LS estimates M = 95.1089 kg, Fv = 203.5034 N s/m,
    Fc = 20.3935 N, offset = -3.1648 N printed in the data set's EMPS_Description.pdf (the
    parameters its Simulation_EMPS.m uses; restoring.EMPS_PUBLISHED).
    """
    path = require_data('emps') / 'DATA_EMPS.mat'
    res = restoring.run(restoring.validate(restoring.convert('emps', path)), plots=False)
    assert 'force_offset' in res['parameters']
    assert {'coulomb_friction', 'asymmetric_friction'} & set(res['parameters'])
    assert res['nrmse_after'] <= 0.05
    assert restoring.emps_comparison(res)['within_10_percent']


def test_the_rate_is_the_one_the_printed_times_imply():
    """A time column stored in single precision (as DATA_EMPS.mat's t) gives 1000 Hz exactly.

    The median step of such a column gives 1000.016 Hz (EMPS); the rate comes from
    rths_common.timebase like every other time-column reader.
    """
    t = (np.arange(24841) / 1000.0).astype(np.float32)
    x = np.sin(2 * np.pi * 0.5 * t.astype(float))
    data = restoring.validate({'time_s': t, 'displacement_m': x, 'force_N': 3.0 * x})
    assert data['fs'] == 1000.0
    path = require_data('emps') / 'DATA_EMPS.mat'
    assert restoring.validate(restoring.convert('emps', path))['fs'] == 1000.0
