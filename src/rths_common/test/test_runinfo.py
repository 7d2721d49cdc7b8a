"""Run information and params-file helpers (rths_common.runinfo)."""

import pytest

from rths_common import runinfo


def test_flatten_and_section_round_trip():
    info = runinfo.flatten('rths', 1024.0, 'lockstep', {
        'numerical': {'record': 'kobe', 'scale': 0.135, 'interface_dofs': [2], 'fs_hz': 1024.0,
                      'taps': [1.0, 2.0]},
        'bridge': {'dtm': 'valve4', 'autostart': True},
        'compensator': {'scheme': 'wls',
                        'provenance': {'created': '2026-11-21T10:31:03+00:00', 'n_taps': 400}}})
    assert all(isinstance(v, str) for v in info.values())  # rosbag2 custom_data holds strings
    assert info['fs_hz'] == '1024.0' and info['kind'] == 'rths'
    assert 'numerical.taps' not in info  # long arrays are not run information
    assert runinfo.section(info, 'numerical') == {'record': 'kobe', 'scale': 0.135,
                                                  'interface_dofs': [2], 'fs_hz': 1024.0}
    assert runinfo.section(info, 'bridge') == {'dtm': 'valve4', 'autostart': True}
    # an ISO time stays text (YAML would read it as a datetime, which JSON cannot write)
    # a nested mapping (the compensator's provenance) becomes dotted keys, as ROS names them
    assert runinfo.section(info, 'compensator') == {
        'scheme': 'wls', 'provenance.created': '2026-11-21T10:31:03+00:00',
        'provenance.n_taps': 400}


def test_params_file_round_trip_keeps_types(tmp_path):
    params = {'taps': [1.0, -0.5], 'fs_hz': 1024.0, 'scheme': 'wls', 'n_taps': 400}
    path = runinfo.write_params(tmp_path / 'c.yaml', 'compensator', params)
    assert runinfo.load_params(path, 'compensator') == params


def test_load_params_names_file_and_layout(tmp_path):
    bad = tmp_path / 'bad.yaml'
    bad.write_text('compensator:\n  taps: [1.0]\n')
    with pytest.raises(ValueError, match=r'bad\.yaml.*ros__parameters'):
        runinfo.load_params(bad, 'compensator')
    with pytest.raises(OSError, match='not found'):
        runinfo.load_params(tmp_path / 'missing.yaml', 'numerical')
