"""Tests of the pysindy / sysidentpy baselines (rths_discrepancy.baselines)."""

import re

import numpy as np
import pytest

from rths_discrepancy import baselines as bl
from rths_discrepancy import models, selftest

pytest.importorskip('pysindy')
pytest.importorskip('sysidentpy')


def test_sindy_names_friction_with_clean_velocity_and_a_tuned_threshold():
    # clean measured signals: the finite-difference velocity is accurate (no sensor noise)
    data, truth = selftest.make_record('specimen', ['coulomb_friction'], 0, duration_s=4.0,
                                       noise=0.0)
    fc_over_m = truth['coulomb_friction'] / models.default_model('specimen').m_d
    assert fc_over_m < bl.DEFAULT_THRESHOLD  # 8 N / 258 kg = 0.031 m/s^2 < 0.1
    fits = bl.sindy_baseline('specimen', data, thresholds=(0.3 * fc_over_m,
                                                           bl.DEFAULT_THRESHOLD))
    tuned = fits[0.3 * fc_over_m]
    assert tuned['named'] == 'coulomb_friction'
    assert tuned['coefficients']['sign(v)'] == pytest.approx(-fc_over_m, rel=0.25)
    # with the self-test's sensor noise, the finite-difference states make the same tuned
    # threshold name an effect on a control record too (noise named as physics)
    control, _ = selftest.make_record('specimen', [], 0, duration_s=4.0)
    assert bl.sindy_baseline('specimen', control, thresholds=(0.3 * fc_over_m,))[
        0.3 * fc_over_m]['named'] != 'none'
    # pysindy's default threshold removes the friction term; the velocity term absorbs it
    assert fits[bl.DEFAULT_THRESHOLD]['coefficients']['sign(v)'] == 0.0
    assert fits[bl.DEFAULT_THRESHOLD]['named'] == 'viscous_damping_error'


def test_sindy_finite_difference_noise_biases_the_stiffness_term_on_a_control():
    """A noisy control (no effect): FD acceleration noise correlates with x (-2 sigma^2/h^2)."""
    data, _ = selftest.make_record('specimen', [], 0, duration_s=8.0)
    fit = bl.sindy_baseline('specimen', data, diff='fd')[bl.DEFAULT_THRESHOLD]
    sigma2 = (selftest.NOISE * np.std(data['rel_disp'])) ** 2
    expected = -2.0 * sigma2 * selftest.FS_HZ ** 2 / np.var(data['rel_disp'])
    assert fit['named'] != 'none'
    assert fit['coefficients']['x'] == pytest.approx(expected, rel=0.3)
    # noise-free, the same control is 'none'
    clean, _ = selftest.make_record('specimen', [], 0, duration_s=8.0, noise=0.0)
    assert bl.sindy_baseline('specimen', clean)[bl.DEFAULT_THRESHOLD]['named'] == 'none'


def test_narx_returns_lagged_polynomial_terms_and_a_free_run_error():
    data, _ = selftest.make_record('actuator', ['cubic_stiffness'], 1, duration_s=4.0)
    res = bl.narx_baseline('actuator', data)
    assert res['terms']
    lagged = re.compile(r'^((y|x1)\(k-\d+\)(\^\d+)?)+$')
    assert all(lagged.match(t) for t in res['terms']), res['terms']
    assert any('x1' in t for t in res['terms'])  # the command enters the model
    assert res['free_run_nrmse'] is not None and 0.0 <= res['free_run_nrmse'] < 1.0


def test_summary_counts_pairs_by_the_kept_set_and_controls_by_the_top_effect():
    def row(expected, named, named_set):
        fit = {'named': named, 'named_set': named_set}
        sweep = {repr(float(th)): fit for th in bl.THRESHOLD_SWEEP}
        return {'scenario': 'specimen', 'label': expected, 'seed': 0, 'expected': expected,
                'baselines': {'sindy_default': fit, 'sindy': {d: sweep for d in bl.DIFFS},
                              'narx': {'terms': ['y(k-1)'], 'free_run_nrmse': 0.5}}}
    pair = 'coulomb_friction+stiffness_error'
    rows = [row('none', 'stiffness_error', 'stiffness_error'), row('none', 'none', 'none'),
            row(pair, 'stiffness_error', pair), row('backlash', 'stiffness_error',
                                                    'stiffness_error')]
    s = bl.summarize(rows)
    assert s['sindy_default']['false_effects_on_controls'] == 1
    assert s['sindy_default']['correct_naming_percent'] == pytest.approx(50.0)
    assert s['narx']['correct_naming_percent'] == 0.0
