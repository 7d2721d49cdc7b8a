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
