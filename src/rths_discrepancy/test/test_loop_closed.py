"""The updated actuator model of the workflow, as the compensator design reads it."""

import numpy as np
import pytest
import yaml

from rths_compensator.identification import load_plant
from rths_compensator.plants import discrete_actuator
from rths_discrepancy import models

FS = 1024.0


def _arx_spec(effects):
    b, a = discrete_actuator('3pole', FS)
    return {'kind': 'arx', 'fs_hz': FS, 'na': a.size - 1, 'nb': b.size, 'd': 0,
            'a': a.tolist(), 'b': b.tolist(), 'effects': effects}


@pytest.mark.parametrize('effects', [
    {'stiffness_error': 0.05},
    {'viscous_damping_error': 2e-3, 'mass_error': 3e-6},
    {'time_delay': 3 / FS, 'stiffness_error': -0.03},
])
def test_the_design_plant_is_the_workflow_model(tmp_path, effects):
    """updated_model.yaml loads as a plant that simulates as the workflow's model."""
    spec = _arx_spec(effects)
    path = tmp_path / 'updated_model.yaml'
    path.write_text(yaml.safe_dump(spec))
    rng = np.random.default_rng(3)
    u = np.r_[np.zeros(8), np.cumsum(rng.normal(0, 1e-5, 3000))]
    expected = models.actuator_from_dict(spec).simulate(u, FS)['measured']
    got = load_plant(path).simulate(u)
    assert np.max(np.abs(got - expected)) <= 1e-9 * np.max(np.abs(expected))


def test_a_fractional_delay_is_close_to_the_workflow_model(tmp_path):
    spec = _arx_spec({'time_delay': 0.002929})
    path = tmp_path / 'updated_model.yaml'
    path.write_text(yaml.safe_dump(spec))
    t = np.arange(4096) / FS
    u = 1e-3 * np.sin(2 * np.pi * 5 * t)
    expected = models.actuator_from_dict(spec).simulate(u, FS)['measured']
    got = load_plant(path).simulate(u)
    assert np.max(np.abs(got - expected)[200:]) <= 1e-3 * np.max(np.abs(expected))
