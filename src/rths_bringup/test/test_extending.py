"""The worked examples of docs/extending.md: each extension is one registry entry, nothing else.

Each test puts a new entry into a registry for the test's duration (``monkeypatch``), as
the entry in the registry's module would, and drives it through the code that chooses by
name (the simulated plant and the reference, the record reader and the substructure,
``rths design``'s design function, the compensator's methods, the bridge), which no test
here edits: so adding one touches its module, its registry entry and its test.
"""

import numpy as np
import pytest

from rths_actuator_bridge.backend import Backend
from rths_actuator_bridge.bridge import BACKENDS, Bridge, make_backend
from rths_actuator_bridge.node import check_bridge_params
from rths_actuator_bridge.simulated import SimulatedPlant
from rths_common.columns import read_columns
from rths_common.timebase import sampling_rate_hz
from rths_compensator.adaptive import AdaptiveMethod, make_method
from rths_compensator.design import Design, design
from rths_compensator.methods import METHODS, Method
from rths_compensator.schemes import SCHEMES, Scheme
from rths_numerical import ground_motion
from rths_numerical.ground_motion import FORMATS, RecordFormat
from rths_numerical.specimens import SPECIMENS, Specimen
from rths_numerical.substructure import make_substructure

FS = 1024.0


# ----------------------------------------------------------------------------- specimen
class SpringDamper:
    """A linear spring-damper between the table and the ground: f = k x + c v."""

    def __init__(self, k_n_m, c_n_s_m):
        self.k, self.c = float(k_n_m), float(c_n_s_m)
        self.x = self.v = 0.0

    def reset(self):
        self.x = self.v = 0.0

    def advance(self, x0, v0, x1, v1, h):
        self.x, self.v = x1, v1

    def force(self):
        return self.k * self.x + self.c * self.v


def test_a_specimen_is_one_entry(monkeypatch):
    entry = Specimen('a linear spring-damper between the floor and the ground',
                     device=lambda settings: SpringDamper(2.0e5, 3.0e3),
                     interface_frame='relative')
    monkeypatch.setitem(SPECIMENS._entries, 'spring_example', entry)
    t = np.arange(int(2 * FS)) / FS
    u = 0.002 * np.sin(2 * np.pi * 1.0 * t)
    plant = SimulatedPlant(specimen='spring_example', daq_filter_hz=0.0)
    rows = [plant.step(uk) for uk in u]
    x = np.array([r['table_disp'] for r in rows])
    v = np.array([r['table_vel'] for r in rows])
    f = np.array([r['force'] for r in rows])
    np.testing.assert_allclose(f, 2.0e5 * x + 3.0e3 * v, atol=1e-6 * np.max(np.abs(f)))
    # the reference: the same law on a perfect actuator (velocity by backward differences)
    ref = entry.reference(1 / FS)
    f_ref = np.array([ref(xk)[0] for xk in u])
    assert np.max(np.abs(f_ref[10:] - (2.0e5 * u + 3.0e3 * np.gradient(u, 1 / FS))[10:])) \
        < 1e-2 * np.max(np.abs(f_ref))
    # what it implies for the numerical substructure: the relative frame, no ground term
    assert entry.numerical_params() == {'interface_frame': 'relative', 'specimen_mass_kg': 0.0}


# ----------------------------------------------------------------------------- record format
def read_acc(path):
    """Read a two-column text record of time [s] and acceleration [cm/s^2] (a ``.acc`` file)."""
    col = read_columns(path, {'time': 0, 'accel': 1}, units={'time': 's', 'accel': 'cm/s^2'})
    return 1.0 / sampling_rate_hz(col['time'], str(path)), col['accel']


def test_a_record_format_is_one_entry(monkeypatch, tmp_path):
    monkeypatch.setitem(FORMATS._entries, 'acc', RecordFormat(
        'two columns: time [s], acceleration [cm/s^2]', ('.acc',), read_acc))
    t = np.arange(1000) * 0.01
    path = tmp_path / 'quake.acc'
    np.savetxt(path, np.column_stack([t, 50.0 * np.sin(2 * np.pi * t)]), fmt='%.6f')
    dt, acc = ground_motion.load_record(str(path))
    assert dt == pytest.approx(0.01) and np.max(np.abs(acc)) == pytest.approx(0.5, rel=1e-3)
    sub = make_substructure({'record': str(path), 'scale': 1.0, 'fs_hz': FS,
                             'duration_s': 2.0})
    assert np.max(np.abs(sub.ag)) > 0.3          # the numerical substructure reads it


# ----------------------------------------------------------------------------- scheme
def design_gain(plant, fs_hz=None, gain=1.0):
    """Design a pure gain (the shape of a design function: plant, rate, its options)."""
    return Design('gain', np.array([float(gain)]), np.array([1.0]), fs_hz or 1024.0,
                  {'gain': float(gain)}).check()


def test_a_compensator_scheme_is_one_entry(monkeypatch):
    monkeypatch.setitem(SCHEMES._entries, 'gain', Scheme('a pure gain', design_gain, ('gain',)))
    plant = ([0.0, 0.5], [1.0, -0.5])             # (b, a) in z^-1
    comp = design(plant, 'gain', fs_hz=FS, gain=2.0, n_taps=100)   # n_taps is not its option
    assert comp.taps.tolist() == [2.0] and comp.info == {'gain': 2.0}


# ----------------------------------------------------------------------------- method
class HoldGain(AdaptiveMethod):
    """An adaptive gain on the designed filter, by normalised LMS on the tracking error."""

    name = 'hold_gain'

    def __init__(self, design, plant, guards=None, mu=0.05):
        super().__init__(design, guards)
        self.gain, self.mu, self._last = 1.0, float(mu), 0.0

    def _command(self, target):
        self._last = target
        return self.gain * target

    def _record(self, measured, adapt):
        if adapt:
            self.gain += self.mu * (self._last - measured) * self._last / (1e-12 + self._last ** 2)

    def coefficients(self):
        return np.array([self.gain])


def test_an_adaptive_method_is_one_entry(monkeypatch):
    monkeypatch.setitem(METHODS._entries, 'hold_gain', Method('an adaptive gain', HoldGain))
    fir = Design('wls', np.array([1.0]), np.array([1.0]), FS)
    method = make_method('hold_gain', fir, plant=object())
    measured = None
    t = np.arange(3000) / FS
    for x in 0.01 * np.sin(2 * np.pi * 2.0 * t):
        u = method.step(x, measured)
        measured = 0.5 * u                          # the plant halves the command
    assert method.coefficients()[0] == pytest.approx(2.0, rel=0.05)
    with pytest.raises(ValueError, match='needs the identified plant'):
        make_method('hold_gain', fir)


# ----------------------------------------------------------------------------- backend
class PerfectActuator(Backend):
    """A backend whose actuator follows every command exactly and measures no force."""

    summary = 'a perfect actuator: displacement = command, force 0'
    params = {'gain_check': (float, 1.0, '[-] an example parameter of the backend')}
    in_process = True

    def _configure(self, params):
        self._x = np.zeros(1)

    def _activate(self):
        self._x[:] = 0.0

    def _deactivate(self):
        """Nothing to stop."""

    def _write(self, command):
        self._x = np.asarray(command, float).copy()

    def _read(self):
        return self._x.copy(), np.zeros_like(self._x)


def test_a_backend_is_one_entry(monkeypatch):
    monkeypatch.setitem(BACKENDS._entries, 'perfect', PerfectActuator)
    params = check_bridge_params({'backend': 'perfect', 'gain_check': 2.0})
    assert isinstance(make_backend(params), PerfectActuator)
    bridge = Bridge()
    bridge.configure(params)
    bridge.activate()
    commands = 1e-4 * np.sin(2 * np.pi * 2.0 * np.arange(200) / FS)   # within every limit
    for k, command in enumerate(commands):
        result = bridge.step(k, np.array([command]))
        assert result.displacement[0] == pytest.approx(command)
    assert 'stopped with it' in PerfectActuator.make_safe(params)
