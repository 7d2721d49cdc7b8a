"""Shared fixtures: both backends behind one parametrised fixture."""

import pytest

from rths_actuator_bridge.backend import make_backend
from rths_actuator_bridge.udp import ControllerEmulator

PLANT = {'dtm': 'valve4', 'actuator_model': '3pole', 'seed': 7,
         'displacement_noise_m': 1e-5, 'force_noise_n': 2.0}


@pytest.fixture
def emulator():
    """A controller emulator on 127.0.0.1 with an ephemeral port, in a thread."""
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
    """A configured (inactive) backend of each kind."""
    b = make_backend(backend_params)
    yield b
    b.close()
