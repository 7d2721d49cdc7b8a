"""The spring-damper specimen: one entry of the registry, through the plant and the reference."""

import numpy as np
import pytest

from rths_actuator_bridge.node import check_bridge_params
from rths_actuator_bridge.simulated import SimulatedPlant
from rths_numerical.specimens import SPECIMENS, specimen_settings

FS = 1024.0


def test_the_plant_and_the_reference_give_k_x_plus_c_v():
    t = np.arange(int(2 * FS)) / FS
    u = 0.002 * np.sin(2 * np.pi * 1.0 * t)
    plant = SimulatedPlant(specimen='spring', spring_k_n_m=1.0e5, spring_c_n_s_m=2.0e3,
                           daq_filter_hz=0.0)
    rows = [plant.step(uk) for uk in u]
    x, v, f = (np.array([r[key] for r in rows]) for key in ('table_disp', 'table_vel', 'force'))
    np.testing.assert_allclose(f, 1.0e5 * x + 2.0e3 * v, atol=1e-6 * np.max(np.abs(f)))
    entry = SPECIMENS.entry('spring')
    ref = entry.reference(1 / FS, {'spring_k_n_m': 1.0e5, 'spring_c_n_s_m': 2.0e3})
    f_ref = np.array([ref(xk)[0] for xk in u])
    want = 1.0e5 * u + 2.0e3 * np.gradient(u, 1 / FS)
    assert np.max(np.abs(f_ref - want)[10:]) < 1e-2 * np.max(np.abs(want))
    # between the floor and the ground: the table follows the relative floor motion
    assert entry.numerical_params() == {'interface_frame': 'relative', 'specimen_mass_kg': 0.0}


def test_its_parameters_are_checked_where_the_bridges_are():
    assert check_bridge_params({'specimen': 'spring', 'spring_k_n_m': 5.0e4})['spring_k_n_m'] \
        == 5.0e4
    with pytest.raises(ValueError, match=r'spring_c_n_s_m = -1.0 is outside its range'):
        specimen_settings('spring', ['spring_c_n_s_m=-1'], '--specimen-param')
