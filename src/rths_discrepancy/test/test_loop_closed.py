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


def test_the_feed_forward_holds_the_non_linear_loads(tmp_path):
    """The Coulomb and cubic loads of an updated model: rths design's feed-forward holds them.

    The plant is the workflow's simulator with the loads (d_c 1e-4 m, k3 400 1/m^2: the
    bench's larger sizes); the compensator is designed on the updated model, with and
    without its loads as the core's feed-forward.  The tracking error of a 1 Hz + 3 Hz
    motion of a few mm falls from the loads' size to a tenth of it or less.
    """
    from rths_compensator import design as dsg
    from rths_compensator.core import CompensatorCore
    from rths_compensator.feedforward import feedforward_params

    loads = {'coulomb_friction': 1e-4, 'cubic_stiffness': 400.0}
    spec = _arx_spec(loads)
    path = tmp_path / 'updated_model.yaml'
    path.write_text(yaml.safe_dump(spec))
    updated = load_plant(path)
    comp = dsg.design(updated, 'ls', n_taps=200, fc_hz=10.0)
    params = {'scheme': 'ls', 'fs_hz': FS, 'taps': comp.taps.tolist(),
              'denominator': comp.denominator.tolist()}
    t = np.arange(int(4 * FS)) / FS
    x = 4e-3 * np.sin(2 * np.pi * 1.0 * t) + 2e-3 * np.sin(2 * np.pi * 3.0 * t)
    x *= np.minimum(t / 0.5, 1.0)
    lab = models.actuator_from_dict(spec)
    errors = {}
    for label, extra in (('linear', {}), ('feed-forward', feedforward_params(updated.loads))):
        core = CompensatorCore(dict(params, **extra))
        u = np.array([core.step(k, [v]).arrays[0][0] for k, v in enumerate(x)])
        y = lab.simulate(u, FS)['measured']
        errors[label] = float(np.sqrt(np.mean((y - x)[1024:] ** 2)) / np.std(x[1024:]))
    assert errors['linear'] > 0.02                        # the loads' size: a few per cent
    assert errors['feed-forward'] < 0.1 * errors['linear']
