"""The limit checks of :mod:`rths_compensator.assessment`: which limit a command exceeds."""

import math

import pytest

from rths_compensator.assessment import DesignLimits, check_limits, exceeded_limits

# the repo's config/bridge.yaml limits (stroke from seed section 4.3.1)
LIMITS = DesignLimits(stroke_m=0.254, velocity_m_s=1.0, acceleration_m_s2=400.0,
                      source='bridge.yaml')


def test_a_command_within_every_limit_exceeds_none():
    assert exceeded_limits({'peak_m': 0.254, 'velocity_m_s': 0.99,
                            'acceleration_m_s2': 10.0}, LIMITS) == []


@pytest.mark.parametrize('key, name, bound', [('peak_m', 'stroke_m', 0.254),
                                              ('velocity_m_s', 'velocity_m_s', 1.0),
                                              ('acceleration_m_s2', 'acceleration_m_s2', 400.0)])
def test_each_limit_is_named_with_its_figure(key, name, bound):
    figures = {'peak_m': 0.01, 'velocity_m_s': 0.1, 'acceleration_m_s2': 1.0}
    figures[key] = 1.5 * bound
    assert exceeded_limits(figures, LIMITS) == [{'limit': name, 'value': 1.5 * bound,
                                                 'bound': bound}]


def test_a_non_finite_command_exceeds_its_limit():
    out = exceeded_limits({'peak_m': math.nan, 'velocity_m_s': math.inf,
                           'acceleration_m_s2': 1.0}, LIMITS)
    assert [e['limit'] for e in out] == ['stroke_m', 'velocity_m_s']


def test_check_limits_lines_name_the_limit_the_figure_and_the_file():
    pred = {'reference_command_peak_m': 0.01, 'reference_command_velocity_m_s': 1.2345,
            'reference_command_acceleration_m_s2': 500.0}
    lines = check_limits(pred, LIMITS, 'a reference')
    assert len(lines) == 2
    assert 'reaches 1.234 m/s, above velocity_m_s = 1 m/s (bridge.yaml)' in lines[0]
    assert 'reaches 500 m/s^2, above acceleration_m_s2 = 400 m/s^2' in lines[1]


def test_a_design_whose_noise_command_exceeds_a_limit_is_redesigned_within_it():
    """4096 Hz, 20 ms: the reference passes, a noise-like target's command did not.

    The plant is case 34 of ``rths bench identification`` (seed 66, 3 poles).  Its default
    design (gain weight 1e-6, gain peak 88 dB at 308 Hz) commands 403 m/s^2 for the bench's
    0-10 Hz noise (0.5 s fades) and passed the reference-only check; with the noise-like
    targets checked the default weight is refused and the next weight is within the limits.
    """
    import numpy as np

    from rths_compensator.assessment import assess, design_within_limits
    from rths_compensator.design import design_default
    from rths_compensator.synthetic import (
        identification_record,
        random_actuator,
        tracking,
        tracking_signals,
    )
    rng = np.random.default_rng(66)
    act = random_actuator(rng, 4096.0, 0.020, 3)
    _, u, y = identification_record(act, 20.0, 40.0, 0.005, 1.0, rng)
    plant = act.model()
    record = (u, y, (2 * u.size) // 3)
    first = design_default(plant)
    pred, violations, _ = assess(plant, first, 10.0, record, LIMITS)
    assert pred['reference_command_acceleration_m_s2'] < 400.0       # the old check passed it
    assert pred['noise_command_acceleration_m_s2'] > 400.0
    assert len(violations) == 1 and 'acceleration_m_s2' in violations[0] \
        and 'band-limited noise' in violations[0]
    comp, band, pred, violations, _, note = design_within_limits(
        plant, lambda w: design_default(plant, **({'gain_weight': w} if w else {})),
        lambda c: c.info['fc_hz'], record, LIMITS)
    assert violations == [] and band == 10.0
    assert comp.info['gain_weight'] > first.info['gain_weight']
    assert 'gain weight raised from 1e-06' in note
    assert pred['noise_command_acceleration_m_s2'] <= 400.0
    for name, x in tracking_signals(4096.0).items():
        tr = tracking(act, comp.taps, comp.denominator, x)
        assert tr['command_acceleration_m_s2'] <= 400.0, name
        assert tr['tracking_pct'] < 0.5, name
