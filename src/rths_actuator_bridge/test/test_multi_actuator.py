"""Several actuators on one specimen: per-actuator limits, the rig file, the simulated rig.

The rig is the maRTHS benchmark's (Condori Uribe et al. 2023; numbers from
github.com/FermandoisLab/maRTHS-bmk-RoDeAC, see rths_common/data/marths.json).
"""

from pathlib import Path

import numpy as np
import pytest
import yaml

from rths_actuator_bridge import marths_rig, safety
from rths_actuator_bridge.bridge import Bridge, check_core_params
from rths_common import yamlfile
from rths_common.marths_data import load_config
from rths_common.rig import ACTUATOR_LIMITS, Rig, load_rig

RIG_FILE = Path(__file__).resolve().parents[3] / 'config' / 'rig_two_actuators.yaml'


def _rig_dict():
    return yamlfile.load(RIG_FILE)


def _stiff_rig(tmp_path) -> str:
    """Write the example rig with load cells and interface forces far beyond the frame's."""
    data = _rig_dict()
    for act in data['rig']['actuators']:
        act['force_n'] = 1e6
    data['rig']['interface_limits'] = {'x_m': 0.025, 'theta_rad': 0.1}
    path = tmp_path / 'rig.yaml'
    path.write_text(yaml.safe_dump(data))
    return str(path)


def _bridge(rig_file=RIG_FILE, **extra):
    b = Bridge()
    b.configure({'backend': 'simulated_rig', 'rig_file': str(rig_file), **extra})
    b.activate()
    return b


def test_the_rig_lists_every_per_channel_limit_of_the_bridge():
    assert ACTUATOR_LIMITS == safety.PER_CHANNEL


def test_each_actuator_has_its_own_limits():
    lim = safety.SafetyLimits.from_params({'stroke_m': [0.03, 0.01], 'velocity_m_s': 20.0,
                                           'acceleration_m_s2': 1e5})
    sup = safety.SafetySupervisor()
    sup.configure(lim)
    sup.activate(np.zeros(2))
    out, state, _ = sup.filter(0, np.array([0.009, 0.009]))
    assert state == safety.ACTIVE and out == pytest.approx([0.009, 0.009])
    # 0.02 m is inside actuator 0's stroke, outside actuator 1's: refused, channel named
    out, state, fault = sup.filter(1, np.array([0.009, 0.02]))
    assert state == safety.HOLD and 'stroke limit' in fault and '(channel 1)' in fault
    assert abs(out[1]) <= 0.01


def test_per_channel_limits_of_the_wrong_length_are_refused():
    with pytest.raises(ValueError, match="'stroke_m' .2 values., 'force_n' .3 values"):
        safety.SafetyLimits.from_params({'stroke_m': [0.1, 0.1], 'force_n': [1.0, 2.0, 3.0]})
    with pytest.raises(ValueError, match=r"'stroke_m\[1\]' = -0.1 must be > 0"):
        safety.SafetyLimits.from_params({'stroke_m': [0.1, -0.1]})
    b = Bridge()
    with pytest.raises(ValueError, match="'stroke_m' lists 2 values but the actuator has 1"):
        b.configure({'backend': 'simulated', 'stroke_m': [0.1, 0.1]})


def test_the_example_rig_file_loads_with_per_actuator_limits():
    rig = load_rig(RIG_FILE)
    assert rig.actuators == ('lower', 'upper') and rig.dofs == ('x', 'theta')
    params = rig.bridge_params({'velocity_m_s': 1.0})
    assert params['stroke_m'] == [0.0299, 0.0296]
    check_core_params({'backend': 'simulated_rig', 'rig_file': str(RIG_FILE)})


def test_a_list_parameter_gives_each_actuator_its_own_limit_beside_the_rig_file():
    """A limit the rig file leaves out: a list parameter gives one value per actuator."""
    data = _rig_dict()
    for act in data['rig']['actuators']:
        act.pop('velocity_m_s')
    rig = Rig.from_dict(data, 'rig file r.yaml')
    params = rig.bridge_params({'velocity_m_s': [0.4, 0.3], 'stroke_m': 0.5})
    assert params['velocity_m_s'] == [0.4, 0.3]
    assert params['stroke_m'] == [0.0299, 0.0296]          # the file's values win
    assert rig.bridge_params({'velocity_m_s': 0.2})['velocity_m_s'] == 0.2   # all alike
    with pytest.raises(ValueError, match=r'parameter velocity_m_s lists 3 values but rig file '
                                         r'r.yaml has 2 actuators \(lower, upper\)'):
        rig.bridge_params({'velocity_m_s': [0.4, 0.3, 0.2]})
    with pytest.raises(ValueError, match=r'parameter stroke_m = 25.4 m is beyond any lab '
                                         'actuator'):
        check_core_params({'backend': 'udp', 'n_channels': 2, 'stroke_m': [0.03, 25.4]})
    lim = check_core_params({'backend': 'udp', 'n_channels': 2, 'stroke_m': [0.03, 0.02]})
    assert lim['stroke_m'] == [0.03, 0.02]


@pytest.mark.parametrize('edit, field', [
    (lambda r: r['actuators'][1].update(stroke_m='3 cm'), r'rig.actuators\[1\].stroke_m'),
    (lambda r: r['actuators'][0].update(strok_m=0.1), r'rig.actuators\[0\]: unknown key'),
    (lambda r: r.update(dofs=['theta', 'x']), 'rig.dofs'),
    (lambda r: r['actuators'].pop(), 'rig.actuators must list one entry per coupler offset'),
    (lambda r: r['coupler'].update(offsets_m=[[0.2, 0.1], [0.3, 0.1]]), 'no independent'),
    (lambda r: r['coupler'].update(kinematics='small'), 'rig.coupler.kinematics'),
    (lambda r: r['interface_limits'].update(x_m=-1), 'rig.interface_limits.x_m'),
    (lambda r: r['actuators'][1].update(name='lower'), r'rig.actuators\[1\].name'),
])
def test_a_bad_rig_file_is_refused_naming_the_field(edit, field):
    data = _rig_dict()
    edit(data['rig'])
    with pytest.raises(ValueError, match=field):
        Rig.from_dict(data, 'rig file x.yaml')


def test_a_rig_file_needs_a_backend_with_as_many_channels():
    b = Bridge()
    with pytest.raises(ValueError, match='lists 2 actuators but backend .simulated. drives one'):
        b.configure({'backend': 'simulated', 'rig_file': str(RIG_FILE)})
    with pytest.raises(ValueError, match='parameter rig_file: .*cannot read'):
        b.configure({'backend': 'simulated_rig', 'rig_file': '/nonexistent/rig.yaml'})


def test_the_simulated_rig_settles_at_the_plants_static_gains(tmp_path):
    """A held command: the measured strokes reach the 2 x 2 plant's static gain times it."""
    cfg = load_config()
    pp = marths_rig.plant_params(cfg)
    dc = np.array([[marths_rig._dc(*e) for e in row] for row in marths_rig._zpk_elements(pp)])
    b = _bridge(_stiff_rig(tmp_path), rig_sensor_noise=0)
    u = np.array([0.002, -0.001])
    steps = [np.zeros(2)] + [u * min(1.0, k / 200) for k in range(1, 3000)]
    for k, cmd in enumerate(steps):
        r = b.step(k, cmd)
    assert r.state == safety.ACTIVE
    assert r.displacement == pytest.approx(dc @ u, rel=1e-3)


def test_the_load_cells_carry_the_frames_force_and_moment_through_the_coupler():
    """Interface channels: (x, theta) of the strokes; J^T f = the frame's (F, M)."""
    cfg = load_config()
    b = _bridge()
    frame = marths_rig.FrameForce(cfg, 1 / 1024.0)
    coupler = marths_rig.rig_coupler(cfg)
    for k in range(600):
        cmd = 0.003 * np.sin(2 * np.pi * 2 * k / 1024) * np.array([1.0, 0.6]) * min(1, k / 300)
        r = b.step(k, cmd)
        x, theta = coupler.dofs(r.displacement, iterations=2)
        f5 = frame.step(x, theta)[0]
        assert r.channels['interface_disp'] == pytest.approx([float(x), float(theta)],
                                                             abs=1e-12)
        assert r.channels['interface_force'] == pytest.approx(f5[:2], rel=1e-9, abs=1e-6)
    assert r.state == safety.ACTIVE and np.max(np.abs(f5[:2])) > 100


def test_an_interface_limit_stops_the_rig_before_the_command_is_sent(tmp_path):
    # both actuators inside their strokes, the translation beyond x_m = 0.025 m
    b = _bridge(_stiff_rig(tmp_path), rig_sensor_noise=0)
    applied = []
    for k in range(2000):
        cmd = np.full(2, min(0.028, 0.028 * k / 600))
        r = b.step(k, cmd)
        if r.applied.size:
            applied.append(r.applied)
        if r.state != safety.ACTIVE:
            break
    assert 'interface limit: command translation x' in r.fault and '(x_m)' in r.fault
    x = [b.rig.to_dofs(a)[0] for a in applied]
    assert max(abs(float(v)) for v in x) <= 0.025 + 1e-12


@pytest.mark.parametrize('version', [1, 2])
def test_a_two_channel_servo_controller_over_udp_takes_its_channel_count_from_the_rig(
        tmp_path, version):
    """The UDP protocol carries one value per channel (both versions): n_channels = actuators."""
    from conftest import PLANT

    from rths_actuator_bridge.emulator import ControllerEmulator

    emu = ControllerEmulator(PLANT, n_channels=2).start()
    try:
        b = Bridge()
        b.configure(dict(PLANT, backend='udp', port=emu.address[1], protocol_version=version,
                         rig_file=_stiff_rig(tmp_path)))
        assert b.backend.n_channels == 2
        b.activate()
        for k in range(50):
            r = b.step(k, np.array([1e-5, -1e-5]) * k)
        assert r.state == safety.ACTIVE and r.displacement.shape == (2,)
        x, theta = b.rig.to_dofs(r.displacement)
        assert r.channels['interface_disp'] == pytest.approx([float(x), float(theta)])
        assert abs(float(theta)) > 1e-4       # opposite strokes rotate the coupler
        b.park()
        b.cleanup()
    finally:
        emu.stop()


def test_an_n_channels_that_disagrees_with_the_rig_file_is_refused(tmp_path):
    from conftest import PLANT

    with pytest.raises(ValueError, match=r"'n_channels' = 3 disagrees with .*lists 2 actuators"):
        Bridge().configure(dict(PLANT, backend='udp', port=1, n_channels=3,
                                rig_file=_stiff_rig(tmp_path)))


def test_a_fault_brings_each_actuator_to_its_own_safe_position_within_its_own_limits():
    lim = safety.SafetyLimits.from_params({
        'stroke_m': [0.03, 0.02], 'velocity_m_s': [0.05, 0.02],
        'acceleration_m_s2': [50.0, 10.0], 'safe_position_m': [0.005, -0.004],
        'ramp_time_s': 0.1, 'hold_time_s': 0.01})
    sup = safety.SafetySupervisor()
    sup.configure(lim)
    sup.activate(np.array([0.01, 0.01]))
    sup.emergency_stop('test')
    outs = [sup.pos.copy()]
    for k in range(20000):
        out, state, _ = sup.filter(k, None)
        outs.append(out)
        if state == safety.STOPPED:
            break
    assert state == safety.STOPPED
    pos = np.array(outs)
    vel = np.diff(pos, axis=0) * lim.fs_hz
    acc = np.diff(vel, axis=0) * lim.fs_hz
    assert pos[-1] == pytest.approx([0.005, -0.004], abs=1e-9)
    assert np.all(np.max(np.abs(vel), axis=0) <= np.array([0.05, 0.02]) * (1 + 1e-9))
    assert np.all(np.max(np.abs(acc), axis=0) <= np.array([50.0, 10.0]) * (1 + 1e-6))
    # the slower actuator really is limited by its own, tighter limit
    assert np.max(np.abs(vel[:, 1])) > 0.9 * 0.02 and np.max(np.abs(vel[:, 0])) > 0.03
