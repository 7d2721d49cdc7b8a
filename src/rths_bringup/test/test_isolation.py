"""Runs isolated from each other: a ROS domain held per run, refused naming its holder."""

import os
import socket
import subprocess
import sys

import pytest

from rths_bringup import isolation

CLAIM = ('import sys; from rths_bringup import isolation\n'
         'try:\n'
         '    r = isolation.claim({"ROS_DOMAIN_ID": sys.argv[1]}, "second run")\n'
         '    print("claimed", r.domain)\n'
         'except ValueError as err:\n'
         '    print(err)\n')


def free_domain() -> int:
    """Return a domain of 101..232 whose port nobody holds now."""
    for domain in range(101 + os.getpid() % 100, isolation.MAX_DOMAIN + 1):
        with socket.socket() as sock:
            try:
                sock.bind(('', isolation.PORT_BASE + domain))
            except OSError:
                continue
            return domain
    pytest.skip('no free domain port on this host')


def other_process(domain: int, env) -> str:
    """Claim ``domain`` from another process; return what it printed."""
    return subprocess.run([sys.executable, '-c', CLAIM, str(domain)], capture_output=True,
                          text=True, env=env, check=True, timeout=60).stdout


@pytest.fixture
def owner_dir(tmp_path, monkeypatch):
    monkeypatch.setenv('RTHS_DOMAIN_DIR', str(tmp_path))
    return tmp_path


def test_a_held_domain_is_refused_naming_the_run_that_holds_it(owner_dir):
    domain = free_domain()
    held = isolation.claim({'ROS_DOMAIN_ID': str(domain)}, 'rths run --out /data/first')
    try:
        said = other_process(domain, dict(os.environ))
        assert f'ROS domain {domain} (ROS_DOMAIN_ID) is in use by another rths run' in said
        assert f'rths run --out /data/first (pid {os.getpid()}' in said
        assert 'unset ROS_DOMAIN_ID' in said
    finally:
        isolation.release(held)
    assert not list(owner_dir.glob('rths-domain-*'))        # the note goes with the claim
    assert f'claimed {domain}' in other_process(domain, dict(os.environ))


def test_a_domain_held_by_another_program_is_refused_naming_its_port(owner_dir):
    domain = free_domain()
    with socket.socket() as sock:
        sock.bind(('', isolation.PORT_BASE + domain))
        with pytest.raises(ValueError, match=f'another process on this host .* TCP port '
                                             f'{isolation.PORT_BASE + domain}'):
            isolation.claim({'ROS_DOMAIN_ID': str(domain)}, 'x')


def test_without_ros_domain_id_each_run_takes_a_free_domain_of_its_own(owner_dir):
    env = {}
    with isolation.reserved('first', env) as first:
        assert first.picked and env['ROS_DOMAIN_ID'] == str(first.domain)
        assert first.domain in isolation.FREE_DOMAINS
        # a phase of the same run shares it; another process takes another domain
        with isolation.reserved('phase', env) as phase:
            assert phase is first
        said = subprocess.run(
            [sys.executable, '-c', 'from rths_bringup import isolation\n'
             'print(isolation.claim({}, "second").domain)'],
            capture_output=True, text=True, check=True, timeout=60,
            env={k: v for k, v in os.environ.items() if k != 'ROS_DOMAIN_ID'}).stdout
        assert int(said) != first.domain
    assert 'ROS_DOMAIN_ID' not in env


def test_a_domain_id_that_is_no_domain_is_refused():
    with pytest.raises(ValueError, match="ROS_DOMAIN_ID='300': give a ROS domain 0..232"):
        isolation.claim({'ROS_DOMAIN_ID': '300'}, 'x')


def test_run_identities_differ_and_travel_in_a_frame_id():
    from rths_common.transport import check_run_id

    a, b = isolation.new_run_id(), isolation.new_run_id()
    assert a != b and check_run_id(a) == a
