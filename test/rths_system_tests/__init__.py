"""Helpers of the rths system tests: find the installed tools, run them, read bags."""

import os
from pathlib import Path
import re
import subprocess
import sys

REPO = Path(__file__).resolve().parents[1]


def rths_executable() -> str:
    """Path of the installed ``rths`` command (found through the ament index)."""
    from ament_index_python.packages import get_package_prefix

    return str(Path(get_package_prefix('rths_bringup')) / 'lib' / 'rths_bringup' / 'rths')


def rths(*args, timeout=300, check=True, **kwargs) -> subprocess.CompletedProcess:
    """Run ``rths ARGS`` and return the completed process (text output)."""
    proc = subprocess.run([rths_executable(), *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, env=test_env(), **kwargs)
    if check and proc.returncode != 0:
        sys.stderr.write(proc.stdout[-4000:] + proc.stderr[-4000:])
        raise AssertionError(f'rths {" ".join(map(str, args))} exited {proc.returncode}')
    return proc


def test_env() -> dict:
    """Environment of a test run: a private ROS domain per pytest process, localhost only."""
    env = dict(os.environ)
    env.setdefault('ROS_DOMAIN_ID', str(20 + os.getpid() % 80))
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    env['RTHS_ROOT'] = str(REPO)
    return env


def started_pids(output: str) -> dict:
    """``{node: pid}`` from the launcher's 'started NAME (pid N)' lines."""
    return {m.group(1): int(m.group(2))
            for m in re.finditer(r'started (\w+) \(pid (\d+)\)', output)}
