"""Tests of the discrepancy workflow (issue 7) on short synthetic records.

Nominal models: Table 4 valve #4 DTM (eq. 46-47) and Table 1 3-pole actuator.
"""

import json
import math
import os

import numpy as np
import pytest
import yaml

from rths_discrepancy import effects as fx
from rths_discrepancy import io as dio
from rths_discrepancy import models, selftest, workflow
from rths_discrepancy.workflow import run_discrepancy

SHORT_S = 8.0


def _case(scenario, hidden, seed=0, strength=1.0):
    data, truth = selftest.make_record(scenario, hidden, seed, duration_s=SHORT_S,
                                       strength=strength)
    return data, truth, run_discrepancy(scenario, data, plots=False)


@pytest.mark.parametrize('scenario, name', [(sc, n) for sc in fx.SCENARIOS
                                            for n in fx.EFFECT_NAMES if n in fx.LIBRARY[sc]])
def test_each_effect_is_named_and_recovered(scenario, name):
    data, truth, res = _case(scenario, [name], seed=1)
    assert res['effect'] == name, res['best_candidate']
    got = res['parameters'][name][fx.LIBRARY[scenario][name].param]
    assert abs(got - truth[name]) <= 0.15 * abs(truth[name])
    if name != 'force_offset':   # a load-cell offset leaves the displacement output alone
        assert res['nrmse_after'] < 0.5 * res['nrmse_before']
        assert res['gap_closed'] > 0.9
    # the named effect pays for its parameters on unseen data (held-out BIC below nominal)
    assert res['information_criterion'][name] < res['information_criterion_none']


@pytest.mark.parametrize('scenario', fx.SCENARIOS)
@pytest.mark.parametrize('seed', [0, 1])
def test_controls_name_no_effect(scenario, seed):
    _, _, res = _case(scenario, [], seed=seed)
    assert res['effect'] == 'none'
    assert res['parameters'] == {}
    # nothing found: no per-band "x noise" ratios that read as a finding (issue 35)
    (line,) = res['localization']['summary']
    assert 'nothing to localise' in line and 'x noise' not in line
    assert res['localization']['residual_rms_to_noise'] < 2.0
    # the noise floor estimate matches the 0.5 % noise added by the generator
    assert res['nrmse_noise'] == pytest.approx(selftest.NOISE, rel=0.2)


def test_pair_is_named_jointly():
    _, truth, res = _case('specimen', ['coulomb_friction', 'stiffness_error'], seed=2)
    assert res['effect'] == 'coulomb_friction+stiffness_error'
    ic = res['information_criterion']   # the pair's extra parameter pays for itself
    assert ic[res['effect']] < min(v for k, v in ic.items() if '+' not in k)
    assert ic[res['effect']] < res['information_criterion_none']
    for name in ('coulomb_friction', 'stiffness_error'):
        got = res['parameters'][name][fx.LIBRARY['specimen'][name].param]
        assert abs(got - truth[name]) <= 0.15 * abs(truth[name])


def test_first_order_lag_is_unexplained():
    _, _, res = _case('specimen', ['_lag'])
    assert res['effect'] == 'unexplained'
    assert 'unexplained_note' in res
    assert res['parameters'] == {}


def test_effect_below_its_detection_limit_is_not_named_as_another():
    """A 0.08 N Coulomb friction (strength 0.01 of the detectability sweep, seed 0).

    Below the detection limit a viscous error explains the small residual as well
    as a friction law does: the answer is 'unexplained' with the tie as the reason
    (the sweep of the v1 rule named it viscous_damping_error).
    """
    data, truth = selftest.make_record('specimen', ['coulomb_friction'], 0, strength=0.01)
    assert truth['coulomb_friction'] == pytest.approx(0.08)
    res = run_discrepancy('specimen', data, plots=False)
    assert res['effect'] == 'unexplained'
    assert res['rival_ic_margin'] < workflow.DISTINCT_IC
    assert 'explain it equally well' in res['unexplained_note']


def test_stribeck_friction_is_named_coulomb():
    _, _, res = _case('specimen', ['_stribeck'])
    assert res['effect'] == 'coulomb_friction'


def _write(tmp_path, data, cols, name='m.csv'):
    path = tmp_path / name
    dio.write_csv(path, data, cols)
    return str(path)


def test_bad_inputs_name_the_problem(tmp_path):
    data, _ = selftest.make_record('actuator', [], 0, duration_s=SHORT_S)
    cols = ('time', 'command', 'measured')
    with pytest.raises(ValueError, match='missing column.*measured'):
        dio.load_csv(_write(tmp_path, data, ('time', 'command')), 'actuator')
    bad = dict(data)
    bad['measured'] = data['measured'].copy()
    bad['measured'][10] = np.nan
    with pytest.raises(ValueError, match='measured has 1 NaN'):
        dio.load_csv(_write(tmp_path, bad, cols), 'actuator')
    bad = dict(data)
    bad['time'] = data['time'].copy()
    bad['time'][100:] += 0.5 / 1024
    with pytest.raises(ValueError, match='not uniformly sampled'):
        dio.load_csv(_write(tmp_path, bad, cols), 'actuator')
    short = {k: v[:300] for k, v in data.items()}
    with pytest.raises(ValueError, match='too short'):
        dio.load_csv(_write(tmp_path, short, cols), 'actuator')
    with pytest.raises(ValueError, match='missing column'):
        run_discrepancy('specimen', data)


def test_seed_models_and_timing_convention():
    spec = models.default_model('specimen')
    assert (spec.m_d, spec.c_d, spec.k_d) == (258.35, 491.6, 80810.0)  # Table 4, valve #4
    fs = 1024.0
    # eq. 47 at the natural frequency: |T| = m_d / (c_d omega_n)
    wn = math.sqrt(spec.k_d / spec.m_d)
    t = np.arange(int(40 * fs)) / fs
    x = spec.simulate(np.sin(wn * t), fs)['rel_disp']
    amp = np.max(np.abs(x[-int(2 * fs):]))
    assert amp == pytest.approx(spec.m_d / (spec.c_d * wn), rel=0.01)
    act = models.default_model('actuator')
    y = act.simulate(np.ones(2048), fs)['measured']
    assert y[0] > 0.0          # d = 0: the sample labelled 0 is read at the end of sample 0
    assert y[-1] == pytest.approx(1.0, abs=1e-3)   # eq. 3: unit DC gain
    # the same plant as an ARX YAML (ZOH discretisation, d = 0) predicts the same output
    b, a = act.linear_filter(fs)
    arx = models.model_from_dict('actuator', {'kind': 'arx', 'fs_hz': fs, 'na': len(a) - 1,
                                              'nb': len(b), 'd': 0, 'a': a.tolist(),
                                              'b': b.tolist()})
    u = selftest.excitation('actuator', 2.0, fs, 0)
    np.testing.assert_allclose(arx.simulate(u, fs)['measured'], act.simulate(u, fs)['measured'],
                               atol=1e-12)


def test_cli_end_to_end_and_updated_model_reloads(tmp_path):
    from rths_bringup.cli import main
    data, truth = selftest.make_record('specimen', ['coulomb_friction'], 3,
                                       duration_s=SHORT_S)
    csv = _write(tmp_path, data, dio.COLUMNS['specimen'])
    out = tmp_path / 'out'
    assert main(['discrepancy', '--scenario', 'specimen', '--measured', csv,
                 '--out', str(out)]) == 0
    res = json.loads((out / 'result.json').read_text())
    assert res['effect'] == 'coulomb_friction'
    for key in ('parameters', 'nrmse_before', 'nrmse_after', 'gap_closed', 'candidates'):
        assert key in res
    assert set(fx.LIBRARY['specimen']) <= set(res['candidates'])
    assert res['nrmse_after'] < 0.2 * res['nrmse_before']
    report = (out / 'report.md').read_text()
    assert 'coulomb_friction' in report
    for png in ('residuals.png', 'residual_spectrum.png', 'residual_state.png'):
        assert os.path.getsize(out / png) > 1000 and png in report
    updated = yaml.safe_load((out / 'updated_model.yaml').read_text())
    assert updated['effects']['coulomb_friction'] == pytest.approx(truth['coulomb_friction'],
                                                                   rel=0.15)
    out2 = tmp_path / 'out2'
    assert main(['discrepancy', '--scenario', 'specimen', '--measured', csv,
                 '--model', str(out / 'updated_model.yaml'), '--out', str(out2)]) == 0
    assert json.loads((out2 / 'result.json').read_text())['effect'] == 'none'
    # a user error exits with code 2 and writes nothing
    out3 = tmp_path / 'out3'
    assert main(['discrepancy', '--scenario', 'actuator', '--measured', csv,
                 '--out', str(out3)]) == 2
    assert not out3.exists()


@pytest.mark.parametrize('name, feature', [('coulomb_friction', 'sign(velocity)'),
                                           ('stiffness_error', 'displacement'),
                                           ('cubic_stiffness', 'displacement^3')])
def test_localisation_points_at_the_state(name, feature):
    _, _, res = _case('specimen', [name], seed=4)
    corr = res['localization']['state']['restoring_force_residual']
    assert max(corr, key=lambda k: abs(corr[k])) == feature


def test_residual_proportional_to_force_is_localised_to_the_force():
    from rths_discrepancy import localize, workflow
    data, _ = selftest.make_record('specimen', [], 7, duration_s=SHORT_S)
    data = dio.validate('specimen', data)
    ctx = workflow.Context('specimen', data, models.default_model('specimen'))
    # a residual r = y - y_nom proportional to the measured damper force (eq. 45), e.g. a
    # displacement transducer picking up the load; the states stay those of the record
    ctx.y = ctx.y_nom + 1e-8 * data['force']
    where = localize.localize(ctx, data)
    corr = where['state']['output_residual']
    # force = c_d xd + k_d x: the displacement alone correlates strongly, but less
    assert max(corr, key=lambda k: abs(corr[k])) == 'force'
    assert abs(corr['force']) > abs(corr['displacement'])
    assert any(line.startswith('state (output residual): force') for line in where['summary'])
    assert 'force' in where['state']['restoring_force_residual']
    # an actuator record has no force column, so no force feature
    act, _ = selftest.make_record('actuator', [], 7, duration_s=SHORT_S)
    act = dio.validate('actuator', act)
    actx = workflow.Context('actuator', act, models.default_model('actuator'))
    assert 'force' not in localize.localize(actx, act)['state']['output_residual']


@pytest.mark.parametrize('hidden', [[], ['coulomb_friction'], ['time_delay']])
def test_specimen_record_at_256_hz(hidden):
    """Any uniform rate is accepted (issue 7): the 1024 Hz record decimated to 256 Hz.

    The physics is simulated at 1024 Hz (4 sub-steps), then every 4th sample is
    kept (the 0-10 Hz BLWN input needs no anti-alias filter at 256 Hz), so the
    workflow's 256 Hz discretisation is not the generator's.  The time delay of
    10 samples at 1024 Hz is 2.5 samples at 256 Hz, outside the alignment band.
    """
    data, truth = selftest.make_record('specimen', hidden, 8, duration_s=SHORT_S)
    data = {k: v[::4] for k, v in data.items()}
    res = run_discrepancy('specimen', data, plots=False)
    assert res['sample_rate_hz'] == pytest.approx(256.0)
    assert res['samples'] == int(SHORT_S * 256)
    assert res['effect'] == (hidden[0] if hidden else 'none')
    for name, value in truth.items():
        got = res['parameters'][name][fx.LIBRARY['specimen'][name].param]
        assert abs(got - value) <= 0.15 * abs(value)
    if hidden:
        assert res['gap_closed'] > 0.9


def test_sensor_bias_shows_in_the_residual_mean():
    _, _, res = _case('actuator', ['sensor_bias'], seed=5)
    assert res['localization']['residual_mean_z'] > 10.0
    assert res['effect'] == 'sensor_bias'


def test_arx_and_pole_model_layouts():
    fs = 1024.0
    act = models.default_model('actuator')
    b, a = act.linear_filter(fs)
    arx = {'kind': 'arx', 'fs_hz': fs, 'na': len(a) - 1, 'nb': len(b), 'd': 0,
           'a': a.tolist(), 'b': b.tolist()}
    data, truth = selftest.make_record('actuator', ['stiffness_error'], 6, duration_s=SHORT_S)
    res = run_discrepancy('actuator', data, model=arx)
    assert res['effect'] == 'stiffness_error'
    assert res['parameters']['stiffness_error']['kappa'] == pytest.approx(
        truth['stiffness_error'], rel=0.15)
    assert res['updated_model']['kind'] == 'arx'
    # Table 1 poles written out as [re, im] pairs give the same model as table1: 3pole
    from rths_compensator.plants import actuator_poles
    poles = [[p.real, p.imag] for p in actuator_poles('3pole')]
    pm = models.model_from_dict('actuator', {'kind': 'continuous', 'poles': poles})
    np.testing.assert_allclose(pm.linear_filter(fs)[0], b, rtol=1e-9)
    with pytest.raises(ValueError, match='fs_hz=512'):
        models.model_from_dict('actuator', {**arx, 'fs_hz': 512.0}).linear_filter(fs)
    with pytest.raises(ValueError, match='unknown effect'):
        models.model_from_dict('specimen', {'kind': 'dtm', 'm_d': 1, 'c_d': 1, 'k_d': 1,
                                            'effects': {'warp_drive': 1.0}})


def test_bench_cli_summary(tmp_path, monkeypatch):
    from rths_bringup.cli import main
    cases = [('specimen', 'control', [], 1.0, 'none'),
             ('specimen', 'coulomb_friction', ['coulomb_friction'], 1.0, 'coulomb_friction'),
             ('specimen', 'first_order_lag', ['_lag'], 1.0, 'coulomb_friction')]
    monkeypatch.setattr(selftest, 'bench_cases', lambda quick=False: cases)
    out = tmp_path / 'bench.json'
    assert main(['bench', 'discrepancy', '--quick', '--workers', '1', '--out', str(out)]) == 0
    summary = json.loads(out.read_text())
    assert summary['cases'] == 3
    # the lag case is deliberately mislabelled: 2 of 3 correct
    assert summary['correct_naming_percent'] == pytest.approx(200.0 / 3)
    assert summary['confusion_matrix']['coulomb_friction'] == {'coulomb_friction': 1,
                                                               'unexplained': 1}
    assert summary['false_effects_on_controls'] == 0
    assert not summary['targets_met']
    assert summary['by_seed']['seeds']['0']['wrong'] == ['first_order_lag']


def test_fractional_delay_is_band_limited_and_exact_for_whole_samples():
    fs = 1024.0
    t = np.arange(4096) / fs
    env = np.exp(-((t - 2.0) / 0.5) ** 2)
    y = np.sin(2 * np.pi * 20.0 * t) * env
    d = fx.delay(y, 3.0 / fs, fs)
    np.testing.assert_allclose(d[3:], y[:-3], atol=1e-12)
    tau = 0.37 / fs
    want = np.sin(2 * np.pi * 20.0 * (t - tau)) * np.exp(-((t - tau - 2.0) / 0.5) ** 2)
    assert np.max(np.abs(fx.delay(y, tau, fs) - want)[200:-200]) < 1e-6


@pytest.mark.parametrize('scenario, convention, lag', [
    ('specimen', 'other_input_hold', 0.4), ('specimen', 'other_output_instant', -1.0),
    ('specimen', 'extra_converter_step', 1.0), ('actuator', 'other_output_instant', 1.0)])
def test_daq_conventions_are_aligned_not_named(scenario, convention, lag):
    """Issue 15: a record whose only difference is a DAQ timing convention is 'none'.

    The alignment (a nuisance parameter of every fit) takes the convention's lag:
    ZOH instead of interpolated input ~0.4-0.5 sample, the output read at the other
    end of the step or one more converter step: 1 sample.
    """
    data, _ = selftest.make_record(scenario, [], 2, duration_s=SHORT_S, convention=convention)
    res = run_discrepancy(scenario, data, plots=False)
    assert res['effect'] == 'none'
    assert res['alignment_samples'] == pytest.approx(lag, abs=0.15)
    assert res['alignment_s'] == pytest.approx(res['alignment_samples'] / 1024.0)
    assert res['nrmse_before'] < res['nrmse_before_unaligned']


@pytest.mark.parametrize('samples, expected', [(1.0, 'none'), (2.0, 'time_delay')])
def test_a_real_delay_of_two_samples_is_named(samples, expected):
    data, _ = selftest.make_record('specimen', [f'_delay_samples:{samples}'], 3,
                                   duration_s=SHORT_S)
    res = run_discrepancy('specimen', data, plots=False)
    assert res['effect'] == expected
    if expected == 'time_delay':
        assert res['parameters']['time_delay']['tau'] * 1024 == pytest.approx(samples, abs=0.1)
    else:
        assert res['alignment_samples'] == pytest.approx(samples, abs=0.1)


def test_effect_under_another_convention_keeps_its_parameter():
    data, truth = selftest.make_record('specimen', ['sensor_bias', 'coulomb_friction'], 4,
                                       duration_s=SHORT_S, convention='extra_converter_step')
    res = run_discrepancy('specimen', data, plots=False)
    assert res['effect'] == 'coulomb_friction+sensor_bias'
    assert res['parameters']['sensor_bias']['bias'] == pytest.approx(truth['sensor_bias'],
                                                                     rel=0.15)
    assert res['alignment_samples'] == pytest.approx(1.0, abs=0.15)


def test_independent_simulator_record_is_named():
    """One record of held-out set B (independent RK2 simulator, 1000 Hz, other conventions)."""
    from rths_discrepancy import heldout
    row = heldout.run_one(('B', 2))   # specimen Coulomb friction + sensor bias
    assert row['expected'] == 'coulomb_friction+sensor_bias'
    assert row['named'] == row['expected']
    assert row['parameters']['F_c'] == pytest.approx(row['truth']['coulomb_friction'], rel=0.15)


def test_detectability_sweep_reports_the_smallest_size(monkeypatch):
    """The sweep's summary: smallest strength named correctly, answers below it."""
    cases = [('specimen', 'force_offset@1e-05', ['force_offset'], 1e-5, 'force_offset'),
             ('specimen', 'force_offset@1', ['force_offset'], 1.0, 'force_offset')]
    monkeypatch.setattr(selftest, 'detect_cases', lambda: cases)
    det = selftest.run_detect(workers=1, duration=SHORT_S)
    d = det['effects']['specimen/force_offset']
    assert d['smallest_strength'] == 1.0
    assert d['smallest_size'] > 0.0
    assert d['answers_below'] == ['none']      # a 0.0005 % load-cell offset is noise
    assert det['false_names_below_total'] == 0
    assert det['effects']['actuator/backlash']['smallest_strength'] is None
