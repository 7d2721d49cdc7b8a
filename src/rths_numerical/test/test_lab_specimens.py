"""A lab's own specimens: spring-damper with a mass, a generic SDOF, a state-space file."""

import numpy as np
import pytest
from scipy import signal

from rths_actuator_bridge.simulated import SimulatedPlant
from rths_numerical.dtm import FRAME_MASS_KG, TABLE4
from rths_numerical.specimens import SPECIMENS

FS = 1024.0
T = np.arange(int(2 * FS)) / FS
U = 0.002 * np.sin(2 * np.pi * 1.5 * T) * np.minimum(1.0, T)


def run_plant(**params):
    plant = SimulatedPlant(daq_filter_hz=0.0, **params)
    rows = [plant.step(uk) for uk in U]
    return {key: np.array([r[key] for r in rows])
            for key in ('table_disp', 'table_vel', 'table_accel', 'force')}


def test_a_spring_damper_with_a_mass_adds_its_inertia_and_its_ground_term():
    settings = {'spring_k_n_m': 1.0e5, 'spring_c_n_s_m': 2.0e3, 'spring_mass_kg': 80.0}
    out = run_plant(specimen='spring', **settings)
    want = 1.0e5 * out['table_disp'] + 2.0e3 * out['table_vel'] + 80.0 * out['table_accel']
    # the mass's acceleration is the sub-step's mean (velocity difference): within 0.5 %
    assert np.max(np.abs(out['force'] - want)[50:]) < 5e-3 * np.max(np.abs(want))
    entry = SPECIMENS.entry('spring')
    # between the floor and the ground: relative frame, the mass's ground term numerically
    assert entry.numerical_params(settings) == {'interface_frame': 'relative',
                                                'specimen_mass_kg': 80.0}


def test_an_oscillator_with_a_dtms_parameters_is_that_dtm():
    dtm = TABLE4['valve4']
    settings = {'oscillator_mass_kg': dtm.m_d, 'oscillator_freq_hz': dtm.f_n,
                'oscillator_zeta': dtm.zeta, 'oscillator_frame_kg': FRAME_MASS_KG}
    mine, seed = run_plant(specimen='oscillator', **settings), run_plant(specimen='valve4')
    np.testing.assert_allclose(mine['force'], seed['force'], rtol=1e-9,
                               atol=1e-9 * np.max(np.abs(seed['force'])))
    entry = SPECIMENS.entry('oscillator')
    assert entry.numerical_params(settings) == SPECIMENS.entry('valve4').numerical_params()
    with pytest.raises(ValueError, match='oscillator_mass_kg = 0 and oscillator_freq_hz = 3 '
                                         'must be > 0'):
        entry.check({'oscillator_mass_kg': 0.0}, 1)


def write_state_space(path, a, b, c, d):
    path.write_text(f'A: {a}\nB: {b}\nC: {c}\nD: {d}\n')
    return str(path)


def test_a_state_space_file_gives_its_own_force(tmp_path):
    # a Maxwell element: spring k in series with a dashpot c, f' = k v - (k / c) f
    k, c = 1.0e5, 5.0e3
    path = write_state_space(tmp_path / 'maxwell.yaml', [[-k / c]], [[0.0, k]], [[1.0]],
                             [[0.0, 0.0]])
    out = run_plant(specimen='statespace', statespace_file=path, mr_substeps=8)
    lti = signal.lti([[-k / c]], [[k]], [[1.0]], [[0.0]])
    _, want, _ = signal.lsim(lti, out['table_vel'], T)
    assert np.max(np.abs(out['force'] - want)[50:]) < 2e-3 * np.max(np.abs(want))
    assert SPECIMENS.entry('statespace').numerical_params({'statespace_file': path}) == {
        'interface_frame': 'relative', 'specimen_mass_kg': 0.0}


def test_a_specimen_that_cannot_run_with_the_model_is_refused_before_the_start(tmp_path):
    entry = SPECIMENS.entry('statespace')
    unstable = write_state_space(tmp_path / 'bad.yaml', [[1.0]], [[0.0, 1.0]], [[1.0]],
                                 [[0.0, 0.0]])
    with pytest.raises(ValueError, match='A is not stable'):
        entry.check({'statespace_file': unstable}, 1)
    with pytest.raises(ValueError, match='missing.yaml: No such file'):
        entry.check({'statespace_file': str(tmp_path / 'missing.yaml')}, 1)
    wrong = write_state_space(tmp_path / 'wrong.yaml', [[-1.0]], [[1.0]], [[1.0]], [[0.0]])
    with pytest.raises(ValueError, match=r'B is \(1, 1\), expected \(1, 2\)'):
        entry.check({'statespace_file': wrong}, 1)
    with pytest.raises(ValueError, match='has 2 interface DOFs, a specimen drives one actuator'):
        SPECIMENS.entry('spring').check({}, 2, 'model frame')
