"""rths run: an explicit option overrides the config file only when given, with a note."""

import argparse

import pytest

from rths_bringup.run import bridge_params, register


def _args(*argv):
    parser = argparse.ArgumentParser()
    register(parser.add_subparsers(), None)
    return parser.parse_args(['run', *argv])


def _bridge(**keys):
    return {'fs_hz': 1024.0, 'position_limit_m': 0.05, **keys}


def test_the_config_specimen_is_kept_without_the_option(tmp_path, capsys):
    params = bridge_params(_bridge(specimen='valve2'), _args(), tmp_path)
    assert params['specimen'] == 'valve2'
    assert 'overrides' not in capsys.readouterr().out


def test_the_former_key_dtm_is_kept_too(tmp_path):
    params = bridge_params(_bridge(dtm='valve1'), _args(), tmp_path)
    assert params['specimen'] == 'valve1'


def test_an_explicit_option_wins_and_the_conflict_is_reported(tmp_path, capsys):
    params = bridge_params(_bridge(specimen='valve2'), _args('--specimen', 'valve3'), tmp_path)
    assert params['specimen'] == 'valve3'
    out = capsys.readouterr().out
    assert '--specimen valve3 overrides specimen: valve2' in out
    assert str(tmp_path / 'bridge.yaml') in out


def test_the_default_applies_when_neither_names_a_specimen(tmp_path):
    from rths_numerical.specimens import DEFAULT_SPECIMEN
    assert bridge_params(_bridge(), _args(), tmp_path)['specimen'] == DEFAULT_SPECIMEN


def test_an_unknown_config_specimen_is_refused_naming_the_file(tmp_path):
    with pytest.raises(ValueError, match='bridge.yaml'):
        bridge_params(_bridge(specimen='valve9'), _args(), tmp_path)


def test_remote_site_bridge_keeps_the_limits_and_drops_the_local_plant():
    from rths_actuator_bridge.bridge import check_core_params
    from rths_bringup.run import remote_bridge
    from rths_common.params import core_params
    local = {'mode': 'lockstep', 'backend': 'simulated', 'fs_hz': 1024.0, 'dtm': 'valve4',
             'actuator_model': '3pole', 'seed': 1, 'stroke_m': 0.2, 'velocity_m_s': 0.5}
    remote = remote_bridge(local, 'tcp://10.0.0.5:8090')
    assert remote == {'mode': 'lockstep', 'backend': 'genericclient', 'fs_hz': 1024.0,
                      'stroke_m': 0.2, 'velocity_m_s': 0.5, 'site': 'tcp://10.0.0.5:8090'}
    check_core_params(core_params(remote))   # a valid bridge of the genericclient backend
    with pytest.raises(ValueError, match='tcp://host:port'):
        remote_bridge(local, 'http://10.0.0.5')
