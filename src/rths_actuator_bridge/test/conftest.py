"""Shared fixtures: both backends behind one parametrised fixture."""

import ast
import os
import signal
import subprocess
import sys

import pytest

from rths_actuator_bridge.bridge import make_backend
from rths_actuator_bridge.emulator import ControllerEmulator

PLANT = {'dtm': 'valve4', 'actuator_model': '3pole', 'seed': 7,
         'displacement_noise_m': 1e-5, 'force_noise_n': 2.0}


@pytest.fixture
def emulator():
    """Return a controller emulator on 127.0.0.1 with an ephemeral port, in a thread."""
    emu = ControllerEmulator(PLANT).start()
    yield emu
    emu.stop()


@pytest.fixture(params=['simulated', 'udp'])
def backend_params(request):
    """Flat parameters of a simulated backend, or of a UDP backend talking to an emulator."""
    if request.param == 'simulated':
        yield dict(PLANT, backend='simulated')
    else:
        emu = ControllerEmulator(PLANT).start()
        yield dict(PLANT, backend='udp', port=emu.address[1], timeout_s=1.0)
        emu.stop()


@pytest.fixture
def backend(backend_params):
    """Return a configured (inactive) backend of each kind."""
    b = make_backend(backend_params)
    yield b
    b.close()


@pytest.fixture
def emulator_process():
    """``controller-emulator`` in its own process; yields ``(port, stats_of_the_stopped_run)``."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    proc = subprocess.Popen(
        [sys.executable, '-m', 'rths_actuator_bridge.cli', 'controller-emulator', '--port', '0',
         '--dtm', 'valve2', '--duration-s', '120'],
        stdout=subprocess.PIPE, text=True, env=env)
    stats = {}

    def stop():
        """Interrupt the emulator; return the datagram counts it printed on exit."""
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=20)
        for line in out.splitlines():
            if line.startswith('controller emulator stopped: '):
                stats.update(ast.literal_eval(line.split(': ', 1)[1]))
        return stats

    try:
        line = proc.stdout.readline()
        assert 'listening on 127.0.0.1:' in line, line
        yield int(line.split('127.0.0.1:')[1].split()[0]), stop
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
