"""The reference re-run with an updated specimen model (rths_discrepancy.rerun), without ROS.

The lab is the simulated plant (3-pole actuator, table, valve #4 DTM, optional
Coulomb friction) in the offline lock-step loop (rths_bringup.offline, the
same cores as the node graph), with a WLS FIR compensator designed on the
discretised Table 1 plant.  The reference is the same substructure coupled
to a numerical DTM (rerun.specimen).
"""

import numpy as np
import pytest

from rths_discrepancy import models, rerun

FRICTION_N = 30.0
NUMERICAL = {'model': 'building2story', 'record': 'kobe', 'scale': 0.135, 'duration_s': 8.0,
             'force_scale': 5.0, 'fs_hz': 1024.0}


@pytest.fixture(scope='module')
def compensator():
    from rths_compensator.design import design
    from rths_compensator.plants import discrete_actuator
    d = design(discrete_actuator('3pole', 1024.0), 'wls', fs_hz=1024.0, n_taps=100, fc_hz=10.0)
    return {'taps': list(d.taps), 'denominator': list(d.denominator)}


def _lab_floor(compensator, friction_n):
    from rths_bringup.offline import offline_rths
    bridge = {'backend': 'simulated', 'fs_hz': 1024.0, 'actuator_model': '3pole',
              'dtm': 'valve4', 'friction_n': friction_n}
    out = offline_rths(NUMERICAL, compensator, bridge)
    hist = out['history']
    return hist['output_disp'], hist


def _reference(model):
    from rths_numerical.reference import coupled_rths
    from rths_numerical.substructure import make_substructure
    sub = make_substructure(NUMERICAL)
    return coupled_rths(sub, rerun.specimen(model, sub.dt))['output_disp']


def _err(x, ref):
    from rths_numerical.reference import relative_rms_error
    return relative_rms_error(x, ref)


def test_updated_reference_matches_an_rths_with_friction(compensator):
    nominal = rerun.run_damper_model({'dtm': 'valve4'})
    updated = models.with_effects(nominal, {'coulomb_friction': FRICTION_N})
    lab, _ = _lab_floor(compensator, FRICTION_N)
    before, after = _err(lab, _reference(nominal)), _err(lab, _reference(updated))
    assert before > 5.0
    assert after < 0.1 * before


def test_friction_reference_is_worse_for_a_linear_lab(compensator):
    """The comparison discriminates: a friction-free lab matches the nominal reference."""
    nominal = rerun.run_damper_model({'dtm': 'valve4'})
    updated = models.with_effects(nominal, {'coulomb_friction': FRICTION_N})
    lab, _ = _lab_floor(compensator, 0.0)
    before, after = _err(lab, _reference(nominal)), _err(lab, _reference(updated))
    assert before < 1.0
    assert after > 5 * before


def test_specimen_effects_and_sensor_effects():
    """Loop effects change the simulated specimen; time_delay/sensor_bias do not."""
    nominal = rerun.run_damper_model({'dtm': 'valve4'})
    t = np.arange(2048) / 1024.0
    table = 0.005 * np.sin(2 * np.pi * 2.81 * t)

    def forces(model):
        spec = rerun.specimen(model, 1 / 1024)
        return np.array([spec(x)[0] for x in table])

    f0 = forces(nominal)
    sensor = models.with_effects(nominal, {'time_delay': 0.01, 'sensor_bias': 1e-3})
    assert np.array_equal(f0, forces(sensor))
    # left out, each with its reason (never silently)
    assert set(rerun.left_out(sensor)) == {'time_delay', 'sensor_bias'}
    # a load-cell offset is in the reading the bridge returns: R + F_0, as the lab's
    # force_offset_n (rths_actuator_bridge.simulated) adds it
    offset = models.with_effects(nominal, {'force_offset': 15.0})
    np.testing.assert_allclose(forces(offset) - f0, 15.0, atol=1e-9)
    assert rerun.left_out(offset) == {}
    for eff in ({'coulomb_friction': 20.0}, {'stiffness_error': 4000.0}, {'mass_error': 10.0}):
        f1 = forces(models.with_effects(nominal, eff))
        assert np.sqrt(np.mean((f1 - f0) ** 2)) > 0.01 * np.sqrt(np.mean(f0 ** 2)), eff


def test_run_parameters_need_run_information_or_config(tmp_path):
    bag = tmp_path / 'bag'
    bag.mkdir()
    with pytest.raises(ValueError, match='--config DIR'):
        rerun.run_parameters(bag)
    with pytest.raises(ValueError, match='dtm: none'):
        rerun.run_damper_model({'dtm': 'none'})


def test_the_reference_cache_simulates_each_reference_once(tmp_path):
    """Cases with the same numerical side share a reference: computed once, then reused."""
    calls = []

    def simulate(value):
        calls.append(value)
        return np.full(4, value)

    key = {'numerical': {'record': 'kobe', 'scale': 0.135}, 'specimen': {'m_d': 258.35}}
    hits = []
    first = rerun._cached(tmp_path, hits, 'coupled', key, lambda: simulate(1.0))
    again = rerun._cached(tmp_path, hits, 'coupled', dict(key), lambda: simulate(2.0))
    np.testing.assert_array_equal(again, first)
    assert calls == [1.0] and hits == ['coupled']
    # anything the reference depends on changes its key: simulated anew
    other = rerun._cached(tmp_path, hits, 'coupled', {**key, 'specimen': {'m_d': 270.0}},
                          lambda: simulate(3.0))
    assert calls == [1.0, 3.0] and other[0] == 3.0
    # no cache directory: always simulated
    rerun._cached(None, hits, 'coupled', key, lambda: simulate(4.0))
    assert calls[-1] == 4.0 and hits == ['coupled']
