"""The load feed-forward of the compensator core (feedforward.py, core.py, params.py)."""

import math

import numpy as np
import pytest

from rths_compensator.core import CompensatorCore
from rths_compensator.feedforward import (
    LoadFeedForward,
    feedforward_params,
    feedforward_settings,
)
from rths_compensator.params import (
    identity_params,
    load_compensator_params,
    write_compensator_params,
)

FS = 1024.0


def _settings(d_c=0.0, k3=0.0, v_eps=1e-3):
    return {'feedforward_coulomb_friction_m': d_c, 'feedforward_cubic_stiffness_1_m2': k3,
            'feedforward_v_eps_m_s': v_eps}


def test_the_load_is_evaluated_mid_sample_on_the_desired_trajectory():
    ff = LoadFeedForward(_settings(d_c=5e-5, k3=200.0), FS)
    x = np.array([0.0, 1e-3, 3e-3, 2e-3])
    got = [float(ff.step([v])[0]) for v in x]
    prev = np.r_[0.0, x[:-1]]
    mid, vel = 0.5 * (x + prev), (x - prev) * FS
    expected = 200.0 * mid ** 3 + 5e-5 * np.tanh(vel / 1e-3)
    assert got == pytest.approx(expected.tolist(), rel=1e-12, abs=1e-18)
    assert got[3] < 0 < got[1]             # the Coulomb load follows the motion's direction


def test_the_core_adds_the_feed_forward_to_the_filters_command():
    base = dict(identity_params(FS), taps=[0.5, 0.25])
    plain, loaded = CompensatorCore(base), CompensatorCore(
        dict(base, feedforward_coulomb_friction_m=1e-4))
    x = 1e-3 * np.sin(2 * np.pi * 2.0 * np.arange(64) / FS)
    diff = [loaded.step(k, [v]).arrays[0][0] - plain.step(k, [v]).arrays[0][0]
            for k, v in enumerate(x)]
    vel = np.diff(np.r_[0.0, x]) * FS
    assert diff == pytest.approx((1e-4 * np.tanh(vel / 1e-3)).tolist(), abs=1e-15)
    assert CompensatorCore(base).feedforward is None     # all zero: off


def test_a_lost_displacement_steps_the_feed_forward_like_the_filter():
    params = dict(identity_params(FS), feedforward_cubic_stiffness_1_m2=1e3)
    core = CompensatorCore(params)
    core.step(0, [1e-3])
    out = core.step(2, [3e-3])            # step 1 lost: interpolated, then step 2
    expected = 3e-3 + 1e3 * (0.5 * (3e-3 + 2e-3)) ** 3
    assert out.arrays[0][0] == pytest.approx(expected, rel=1e-6)


def test_the_params_file_carries_the_feed_forward(tmp_path):
    path = tmp_path / 'compensator.yaml'
    write_compensator_params(path, [1.0], [1.0], FS, 'identity',
                             feedforward=feedforward_params({'coulomb_friction': 5e-5,
                                                             'cubic_stiffness': 200.0}))
    params = load_compensator_params(path)
    assert params['feedforward_coulomb_friction_m'] == 5e-5
    assert params['feedforward_cubic_stiffness_1_m2'] == 200.0
    assert 'feedforward_coulomb_friction_m' not in params['provenance']
    assert CompensatorCore(params).feedforward is not None


@pytest.mark.parametrize('key, value, message', [
    ('feedforward_coulomb_friction_m', -1e-5, 'opposes the motion'),
    ('feedforward_cubic_stiffness_1_m2', math.nan, 'not finite'),
    ('feedforward_v_eps_m_s', 0.0, 'must be > 0'),
    ('feedforward_cubic_stiffness_1_m2', 'big', 'not a number'),
])
def test_a_bad_value_is_refused_with_its_key(key, value, message):
    with pytest.raises(ValueError, match=message) as err:
        feedforward_settings({key: value}, 'compensator.yaml')
    assert key in str(err.value) and 'compensator.yaml' in str(err.value)


def test_a_load_the_feed_forward_does_not_apply_is_refused():
    with pytest.raises(ValueError, match='backlash is not a load it applies'):
        feedforward_params({'backlash': 1e-4})
