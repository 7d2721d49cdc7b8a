"""An updated actuator model's effects folded into the ARX plant, or refused (plant_effects)."""

import numpy as np
import pytest
import yaml

from rths_compensator import design as dsg
from rths_compensator.identification import ArxModel, load_plant
from rths_compensator.plant_effects import fold_effects
from rths_compensator.plants import discrete_actuator

FS = 1024.0


def _nominal():
    b, a = discrete_actuator('3pole', FS)
    return ArxModel(a=a, b=b, d=0, fs_hz=FS)


def _write(tmp_path, plant, effects):
    doc = dict(plant.to_dict(), effects=effects)
    path = tmp_path / 'updated_model.yaml'
    path.write_text(yaml.safe_dump(doc))
    return path


def test_a_whole_sample_delay_is_dead_time():
    plant = _nominal()
    a, b, d = fold_effects(plant.a, plant.b, plant.d, FS, {'time_delay': 3 / FS})
    assert d == plant.d + 3 and np.array_equal(b, plant.b) and np.array_equal(a, plant.a)


def test_a_fractional_delay_interpolates_between_samples():
    plant = _nominal()
    a, b, d = fold_effects(plant.a, plant.b, plant.d, FS, {'time_delay': 2.5 / FS})
    assert d == plant.d + 2 and b.size == plant.b.size + 1
    assert b[0] == pytest.approx(0.5 * plant.b[0])


def test_the_design_on_the_updated_plant_compensates_the_delay(tmp_path):
    """The delay 2.929 ms of the issue's actuator 3: taps differ, the delay is compensated."""
    nominal = _nominal()
    updated = load_plant(_write(tmp_path, nominal, {'time_delay': 0.002929}))
    assert updated.d == nominal.d + 2        # 2.999 samples: 2 whole + 0.999 interpolated
    comp_nom = dsg.design(nominal, 'ls', n_taps=200, fc_hz=10.0)
    comp_upd = dsg.design(updated, 'ls', n_taps=200, fc_hz=10.0)
    assert not np.allclose(comp_nom.taps, comp_upd.taps)
    before = dsg.predict(updated, comp_nom, 10.0)['delay_ms']
    after = dsg.predict(updated, comp_upd, 10.0)['delay_ms']
    assert before == pytest.approx(2.93, abs=0.1)
    assert abs(after) < 0.5


def test_linear_loop_loads_fold_into_the_denominator():
    """A stiffness load kappa y on the servo loop lowers the DC gain to 1 / (1 + kappa)."""
    plant = _nominal()
    a, b, d = fold_effects(plant.a, plant.b, plant.d, FS,
                           {'stiffness_error': 0.25, 'viscous_damping_error': 1e-3,
                            'mass_error': 1e-6})
    folded = ArxModel(a=a, b=b, d=d, fs_hz=FS)
    assert folded.dc_gain() == pytest.approx(plant.dc_gain() / (1 + 0.25 * plant.dc_gain()))


def test_the_non_linear_loads_are_kept_for_the_feed_forward(tmp_path):
    """Coulomb and cubic loads leave the coefficients alone and ride along as ``loads``."""
    nominal = _nominal()
    updated = load_plant(_write(tmp_path, nominal, {'coulomb_friction': 5e-5,
                                                    'cubic_stiffness': 200.0,
                                                    'stiffness_error': 0.02}))
    assert updated.loads == {'coulomb_friction': 5e-5, 'cubic_stiffness': 200.0}
    a, b, d = fold_effects(nominal.a, nominal.b, nominal.d, FS, {'stiffness_error': 0.02})
    assert np.allclose(updated.a, a) and np.allclose(updated.b, b) and updated.d == d


def test_a_negative_coulomb_load_is_refused(tmp_path):
    with pytest.raises(ValueError, match="'coulomb_friction' = -5e-05 is negative"):
        load_plant(_write(tmp_path, _nominal(), {'coulomb_friction': -5e-5}))


@pytest.mark.parametrize('name', ['backlash', 'velocity_saturation', 'sensor_bias',
                                  'no_such_effect'])
def test_an_effect_the_design_cannot_use_is_refused(tmp_path, name):
    path = _write(tmp_path, _nominal(), {name: 1e-4})
    with pytest.raises(ValueError, match=f"updated_model.yaml: effect '{name}' cannot be used"):
        load_plant(path)


def test_a_negative_delay_is_refused():
    plant = _nominal()
    with pytest.raises(ValueError, match='negative'):
        fold_effects(plant.a, plant.b, plant.d, FS, {'time_delay': -1e-3})
