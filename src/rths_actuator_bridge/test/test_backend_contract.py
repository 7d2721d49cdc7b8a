"""Contract tests of the backend interface, run against both backends."""

from conftest import PLANT
import numpy as np
import pytest

from rths_actuator_bridge.bridge import make_backend
from rths_actuator_bridge.simulated import SimulatedPlant


def _sine(n=1500, amp=0.005, f=3.0, fs=1024.0):
    t = np.arange(n) / fs
    return amp * np.sin(2 * np.pi * f * t) * np.minimum(t / 0.5, 1.0)


def test_nothing_moves_before_activation(backend):
    with pytest.raises(RuntimeError):
        backend.write(np.array([0.0]))
    with pytest.raises(RuntimeError):
        backend.read()


def test_declared_limits_are_the_seed_values(backend):
    # seed section 4.3.1 / 5.1.2: stroke +-10 in = 0.254 m, 4 load cells x 2000 N
    assert backend.limits.stroke_m == pytest.approx(0.254)
    assert backend.limits.force_n == pytest.approx(8000.0)


def test_lockstep_matches_the_plant_model(backend):
    """Both backends return exactly the simulated plant's measurement of each step."""
    u = _sine()
    ref = SimulatedPlant(**PLANT)
    backend.activate()
    for uk in u:
        backend.write(np.array([uk]))
        disp, force = backend.read()
        ref.step(uk)
        m = ref.measure()
        assert disp.shape == (1,) and force.shape == (1,)
        assert disp[0] == pytest.approx(m['table_disp'], abs=1e-12)
        assert force[0] == pytest.approx(m['force'], abs=1e-9)
    chans = backend.channels()
    assert chans['rel_disp'] == pytest.approx(ref.measure(ref.true)['rel_disp'], abs=1e-3)
    backend.deactivate()
    with pytest.raises(RuntimeError):
        backend.write(np.array([0.0]))


def test_reactivation_restarts_the_step_count_and_keeps_a_real_actuator_where_it_is(backend):
    """The simulated plant starts again from rest; a controller's actuator keeps its state."""
    u = _sine(300)
    runs = []
    for _ in range(2):
        backend.activate()
        out = []
        for uk in u:
            backend.write([uk])
            out.append(backend.read()[0][0])
        assert backend.step == len(u) - 1
        backend.deactivate()
        runs.append(np.array(out))
    assert np.max(np.abs(runs[0])) > 1e-3
    if not backend.in_process:   # ACTIVATE does not reset the controller's actuator: it starts
        # where the first run left it (3 mm off zero), not at rest at zero
        assert abs(runs[0][-1]) > 2e-3
        assert runs[1][0] == pytest.approx(runs[0][-1], abs=1e-3)
    else:
        np.testing.assert_array_equal(runs[0], runs[1])


def test_rejects_non_finite_and_wrong_size_commands(backend):
    backend.activate()
    for bad in ([np.nan], [np.inf], [0.0, 0.0]):
        with pytest.raises(ValueError):
            backend.write(bad)


def test_make_backend_validates_keys():
    with pytest.raises(ValueError, match="'backend'"):
        make_backend({'backend': 'quantum'})
    with pytest.raises(ValueError, match="'dtm'"):
        make_backend({'dtm': 'valve9'})
    with pytest.raises(ValueError, match="'stroke_m'"):
        make_backend({'stroke_m': -1})
    with pytest.raises(ValueError, match="'port'"):
        make_backend({'backend': 'udp'})
    with pytest.raises(ValueError, match="'fs_hz'"):
        make_backend({'fs_hz': 'fast'})
