"""What rths controls of its security: enclaves' environment, refused keystores, localhost binds.

DDS security itself (SROS2) cannot be tested here: the Fast DDS of the ROS 2
wheels is built without its security plugins. What is tested is what rths does:
each process of a run gets the environment rcl reads to enter its enclave, a
missing keystore or enclave is refused in one line before anything starts,
and the live view and the site listen on localhost unless told otherwise.
"""

import argparse

import pytest

from rths_actuator_bridge.site import SITE_PARAMS, site_params
from rths_bringup.cli import main as rths
from rths_bringup.security import ENCLAVE_ROOT, PROCESSES, enclave_env
from rths_live import live


def _keystore(tmp_path, names=PROCESSES):
    root = tmp_path / 'keystore'
    for name in names:
        (root / 'enclaves' / 'rths' / name).mkdir(parents=True)
    return root


def test_every_process_gets_its_enclave(tmp_path):
    env = enclave_env(_keystore(tmp_path))
    assert set(env) == set(PROCESSES)
    for name, e in env.items():
        assert e['ROS_SECURITY_ENCLAVE_OVERRIDE'] == f'{ENCLAVE_ROOT}/{name}'
        assert e['ROS_SECURITY_ENABLE'] == 'true' and e['ROS_SECURITY_STRATEGY'] == 'Enforce'
        assert e['ROS_SECURITY_KEYSTORE'] == str((tmp_path / 'keystore').resolve())


def test_a_missing_keystore_or_enclave_is_refused_with_the_command_that_makes_it(tmp_path):
    with pytest.raises(ValueError, match='ros2 security create_keystore'):
        enclave_env(tmp_path / 'nowhere')
    with pytest.raises(ValueError, match=r'/rths/bridge.*ros2 security create_enclave'):
        enclave_env(_keystore(tmp_path, ('container', 'recorder')), ('container', 'bridge'))


def test_rths_launch_refuses_a_missing_keystore_before_starting(tmp_path, capsys):
    code = rths(['launch', '--enclave-keystore', str(tmp_path / 'nowhere'), '--duration', '1'])
    err = capsys.readouterr().err
    assert code != 0 and 'create_keystore' in err and 'Traceback' not in err
    assert 'started' not in capsys.readouterr().out


def test_the_live_view_and_the_site_listen_on_localhost_by_default():
    p = argparse.ArgumentParser()
    live.add_arguments(p)
    assert p.parse_args([]).host == '127.0.0.1'
    assert SITE_PARAMS['allow'][0] == ['127.0.0.1', '::1']
    assert site_params({})['allow'] == ['127.0.0.1', '::1']
