"""Simulated plant: Table 1 actuator, eq. 46-47 DTM, force convention, noise, ADC, ARX."""

import os
import sys
import types

import numpy as np
import pytest
from scipy.signal import cont2discrete, freqs, lfilter

from rths_actuator_bridge.bridge import make_backend
from rths_actuator_bridge.simulated import SimulatedPlant
from rths_compensator.plants import continuous_actuator
from rths_numerical.dtm import FRAME_MASS_KG, TABLE4

FS = 1024.0


def _sine(f, amp, seconds=8.0):
    t = np.arange(int(seconds * FS)) / FS
    return amp * np.sin(2 * np.pi * f * t)


@pytest.mark.parametrize('kind', ['3pole', '4pole'])
def test_actuator_matches_table1_model(kind):
    """Steady sine response = |G_a(j w)| and phase of the Table 1 model (eq. 3)."""
    f = 5.0
    p = SimulatedPlant(actuator_model=kind, dtm='none')
    y = p.simulate(_sine(f, 0.01))['table_disp']
    t = np.arange(len(y)) / FS + 1 / FS     # measurement at the end of the sample
    tail = slice(len(y) // 2, None)
    basis = np.column_stack([np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t)])[tail]
    # the command is a ZOH staircase: half a sample of extra delay on top of G_a
    s_c, c_c = np.linalg.lstsq(basis, y[tail], rcond=None)[0]
    num, den = continuous_actuator(kind)
    _, g = freqs(num, den, [2 * np.pi * f])
    g = g[0] * np.exp(-1j * np.pi * f / FS) * np.sinc(f / FS)
    assert complex(s_c, c_c) == pytest.approx(0.01 * complex(g.real, g.imag), abs=2e-6)
    step = SimulatedPlant(actuator_model=kind, dtm='none').simulate(np.ones(2048))
    assert step['table_disp'][-1] == pytest.approx(1.0, abs=1e-6)   # unit DC gain (eq. 3)


@pytest.mark.parametrize('name', ['valve1', 'valve4', 'novalve'])
def test_dtm_channels_obey_eq47_and_force_convention(name):
    dtm = TABLE4[name]
    p = SimulatedPlant(dtm=name)
    m = p.simulate(_sine(2.5, 0.005))
    num, den, _ = cont2discrete(([-dtm.m_d], [dtm.m_d, dtm.c_d, dtm.k_d]), 1 / FS, method='foh')
    rel = lfilter(np.ravel(num), np.ravel(den), m['table_accel'])
    assert np.max(np.abs(rel - m['rel_disp'])) < 1e-3 * np.max(np.abs(m['rel_disp']))
    # measured force = m_frame xdd_s - (c_d xd_d2s + k_d x_d2s) (unfiltered channels)
    p2 = SimulatedPlant(dtm=name, daq_filter_hz=0.0)
    m2 = p2.simulate(_sine(2.5, 0.005))
    expect = FRAME_MASS_KG * m2['table_accel'] - (dtm.c_d * m2['rel_vel']
                                                  + dtm.k_d * m2['rel_disp'])
    np.testing.assert_allclose(m2['force'], expect, atol=1e-8 * np.max(np.abs(expect)))


def test_step_and_batch_agree_and_seed_reproduces_noise():
    params = dict(dtm='valve2', seed=3, displacement_noise_m=1e-4, force_noise_n=5.0)
    u = _sine(3.0, 0.004, 1.0)
    a = SimulatedPlant(**params)
    rows = [a.step(x) for x in u]
    b = SimulatedPlant(**params)
    batch = b.simulate(u)
    true_b = SimulatedPlant(**dict(params, displacement_noise_m=0, force_noise_n=0)).simulate(u)
    for key in ('table_disp', 'force', 'rel_disp', 'table_accel'):    # step() = batch, exactly
        np.testing.assert_allclose([r[key] for r in rows], true_b[key],
                                   atol=1e-9 * np.max(np.abs(true_b[key])))
    noise = batch['table_disp'] - true_b['table_disp']
    assert np.std(noise) == pytest.approx(1e-4, rel=0.1)
    again = SimulatedPlant(**params).simulate(u)
    np.testing.assert_array_equal(again['force'], batch['force'])
    other = SimulatedPlant(**dict(params, seed=4)).simulate(u)
    assert np.any(other['force'] != batch['force'])


def test_adc_quantisation():
    p = SimulatedPlant(dtm='valve4', adc_bits=12, displacement_range_m=0.254)
    d = p.simulate(_sine(1.0, 0.01, 1.0))['table_disp']
    lsb = 2 * 0.254 / 2 ** 12
    np.testing.assert_allclose(d / lsb, np.round(d / lsb), atol=1e-6)
    assert len(np.unique(d)) > 10


def test_coulomb_friction_reduces_the_relative_motion():
    u = _sine(2.0, 0.005, 4.0)
    lin = SimulatedPlant(dtm='novalve').simulate(u)
    fr = SimulatedPlant(dtm='novalve', friction_n=100.0).simulate(u)
    assert np.max(np.abs(fr['rel_disp'])) < 0.8 * np.max(np.abs(lin['rel_disp']))
    small = SimulatedPlant(dtm='novalve', friction_n=1e-9).simulate(u)
    np.testing.assert_allclose(small['rel_disp'], lin['rel_disp'], atol=1e-6)


def test_arx_actuator_from_plant_yaml(monkeypatch, tmp_path):
    """An identified ARX plant (d = 0 convention) drives the same table + DTM."""
    num, den = continuous_actuator('3pole')
    b, a, _ = cont2discrete((num, den), 1 / FS, method='zoh')
    b = np.ravel(b)[1:]            # drop the leading zero: project convention d = 0

    class Arx:
        loads: dict = {}   # (rths_compensator's ArxModel: an updated model's non-linear loads)

    model = Arx()
    model.a, model.b, model.d, model.fs_hz = np.ravel(a), b, 0, FS
    fake = types.ModuleType('rths_compensator.identification')
    fake.load_plant = lambda path: model
    monkeypatch.setitem(sys.modules, 'rths_compensator.identification', fake)
    u = _sine(2.0, 0.005, 4.0)
    arx = SimulatedPlant(actuator_model=str(tmp_path / 'plant.yaml'), dtm='valve4',
                         daq_filter_hz=0).simulate(u)
    ref = SimulatedPlant(actuator_model='3pole', dtm='valve4', daq_filter_hz=0).simulate(u)
    np.testing.assert_allclose(arx['table_disp'], ref['table_disp'], atol=1e-9)
    assert np.max(np.abs(arx['rel_disp'] - ref['rel_disp'])) < 0.01 * np.max(
        np.abs(ref['rel_disp']))
    assert np.max(np.abs(arx['force'] - ref['force'])[10:]) < 0.05 * np.max(np.abs(ref['force']))
    model.fs_hz = 2048.0
    with pytest.raises(ValueError, match='fs_hz'):
        SimulatedPlant(actuator_model='plant.yaml')


def _saved_zoh_plant(tmp_path, d):
    """Return the 3-pole actuator with ``d`` samples of dead time as a plant.yaml.

    Return the 3-pole actuator's exact ZOH model with ``d`` extra samples of dead time, written
    to a plant.yaml by rths_compensator's own save function (as ``rths identify`` does).
    """
    from rths_compensator.identification import ArxModel, save_plant
    num, den = continuous_actuator('3pole')
    b, a, _ = cont2discrete((num, den), 1 / FS, method='zoh')
    model = ArxModel(a=np.ravel(a), b=np.ravel(b)[1:], d=d, fs_hz=FS)
    return save_plant(tmp_path / f'plant_d{d}.yaml', model, {'criterion': 'test'})


REPO_PLANT = os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', '..', '..',
                          'config', 'plant.yaml')


@pytest.mark.parametrize('source', ['saved d=0', 'saved d=2', 'config/plant.yaml'])
def test_arx_actuator_step_response_from_a_real_plant_yaml(tmp_path, source):
    """The simulated plant built from a plant.yaml (real load_plant) follows the ARX model."""
    from rths_compensator.identification import load_plant
    if source == 'config/plant.yaml':
        if not os.path.isfile(REPO_PLANT):
            pytest.skip('no config/plant.yaml in this checkout')
        path = REPO_PLANT            # read only
    else:
        path = _saved_zoh_plant(tmp_path, int(source[-1]))
    model = load_plant(path)
    u = np.full(10 * 1024, 0.005)    # a 5 mm step from rest, 10 s
    expect = model.simulate(u)
    scale = np.max(np.abs(expect))
    assert model.dc_gain() == pytest.approx(1.0, abs=0.05)    # a tracking actuator (eq. 3)
    assert expect[-1] == pytest.approx(0.005 * model.dc_gain(), rel=1e-6)   # settled
    plant = SimulatedPlant(actuator_model=path, dtm='valve4')
    m = plant.simulate(u)
    np.testing.assert_allclose(m['table_disp'], expect, rtol=0, atol=1e-12 * scale)
    assert np.all(m['table_disp'][:model.d] == 0.0)            # the dead time d
    # the same through the backend interface, one write/read per step
    backend = make_backend({'actuator_model': path, 'dtm': 'valve4'})
    backend.activate()
    got = []
    for x in u[:600]:
        backend.write([x])
        got.append(backend.read()[0][0])
    backend.close()
    np.testing.assert_allclose(got, expect[:600], rtol=0, atol=1e-12 * scale)
    # the DTM rides on that table: at rest again 10 s after the step (valve #4, Table 4:
    # f_n 2.8 Hz, zeta 5.4 %, decay time 1 s), it carries no force
    assert abs(m['rel_disp'][-1]) < 1e-3 * np.max(np.abs(m['rel_disp']))
    assert abs(m['force'][-1]) < 1e-3 * np.max(np.abs(m['force']))
    # a loop rate other than the plant's is refused, naming the file and the field
    with pytest.raises(ValueError, match='fs_hz') as err:
        SimulatedPlant(actuator_model=path, fs_hz=2048.0)
    assert os.fspath(path) in str(err.value)


def test_arx_plant_yaml_that_is_missing_names_the_file(tmp_path):
    missing = tmp_path / 'nothing.yaml'
    with pytest.raises(OSError, match='nothing.yaml'):
        SimulatedPlant(actuator_model=str(missing))
