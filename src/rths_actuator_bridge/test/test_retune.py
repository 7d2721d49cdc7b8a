"""SimulatedPlant.retune: a plant change during a run with continuous physical state."""

import numpy as np
import pytest

from rths_actuator_bridge.simulated import RETUNE_KEYS, SimulatedPlant


def _sine(n, fs=1024.0, f=3.0, amp=1e-3):
    return amp * np.sin(2 * np.pi * f * np.arange(n) / fs)


def test_unit_factors_change_nothing():
    u = _sine(2000)
    ref, plant = SimulatedPlant(), SimulatedPlant()
    for k in range(2000):
        if k == 700:
            plant.retune(**dict.fromkeys(RETUNE_KEYS, 1.0))
        a, b = ref.step(u[k]), plant.step(u[k])
    assert a == b


def test_state_stays_continuous_and_the_new_plant_takes_over():
    u = _sine(3000)
    plant = SimulatedPlant()
    rows = [plant.step(v) for v in u[:1500]]
    plant.retune(actuator_gain=0.8, actuator_bandwidth=0.9, actuator_mode_frequency=0.9,
                 dtm_stiffness=0.7)
    rows += [plant.step(v) for v in u[1500:]]
    disp = np.array([r['table_disp'] for r in rows])
    vel = np.array([r['table_vel'] for r in rows])
    jump = np.abs(np.diff(disp))
    # no jump at the change beyond the ordinary per-sample motion
    assert jump[1499] <= 1.5 * np.max(jump[1400:1499])
    assert abs(vel[1500] - vel[1499]) <= 1.5 * np.max(np.abs(np.diff(vel[1400:1499])))
    # steady state: the amplitude follows the new gain (3 Hz is well inside the bandwidth)
    amp_before = np.max(np.abs(disp[800:1500]))
    amp_after = np.max(np.abs(disp[2300:]))
    assert amp_after / amp_before == pytest.approx(0.8, abs=0.03)
    # a plant built with the same factors from rest behaves the same once transients decay
    fresh = SimulatedPlant()
    fresh.retune(actuator_gain=0.8, actuator_bandwidth=0.9, actuator_mode_frequency=0.9,
                 dtm_stiffness=0.7)
    ref = np.array([fresh.step(v)['table_disp'] for v in u])
    np.testing.assert_allclose(disp[2800:], ref[2800:], atol=2e-3 * amp_after)


def test_stiffness_factor_moves_the_dtm_frequency():
    plant = SimulatedPlant()
    plant.retune(dtm_stiffness=0.5)
    m, c, k = plant._dtm_cmk()
    assert k == pytest.approx(0.5 * plant.dtm.k_d)


def test_bad_retune_is_refused():
    plant = SimulatedPlant()
    with pytest.raises(ValueError, match='unknown parameter'):
        plant.retune(stiffness=0.5)
    with pytest.raises(ValueError, match='finite factor'):
        plant.retune(actuator_gain=0.0)


def test_retune_refuses_models_it_cannot_map():
    with pytest.raises(ValueError, match='continuous Table 1'):
        SimulatedPlant(dtm='mr').retune(actuator_gain=0.9)
