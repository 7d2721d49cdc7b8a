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
