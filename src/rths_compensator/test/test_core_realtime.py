"""Every method in the compensator core's realtime path, and the reference PI + lead controller.

* PI + lead: the command is ``G_C (G_T y - x_m)`` of Silva et al. (2020, eq. 23-24),
  checked against SciPy's Tustin discretisation of the same transfer functions; its
  guards (integrator frozen while the bridge holds, fallback on a non-finite
  measurement) and its tracking of the 3-pole actuator model.
* Realtime core: never waits for a measurement; with every message on time it equals
  the lock-step core bit for bit; lost displacements are counted and filled, lost
  measurements leave the commands finite.
"""

import numpy as np
import pytest
from scipy import signal

from rths_compensator.core import CompensatorCore
from rths_compensator.design import design_fir
from rths_compensator.feedback import KI, KP, LEAD, PiLead
from rths_compensator.filters import MultiChannelFilter
from rths_compensator.identification import ArxModel, save_plant
from rths_compensator.methods import METHODS, compensator_names
from rths_compensator.plants import discrete_actuator

FS = 1024.0


@pytest.fixture(scope='module')
def setup(tmp_path_factory):
    b, a = discrete_actuator('3pole', FS)
    design = design_fir((b, a), n_taps=32, fc_hz=64.0, scheme='ls', fs_hz=FS, zero_tol=0.98)
    path = tmp_path_factory.mktemp('plant') / 'plant.yaml'
    save_plant(path, ArxModel(a=a, b=b, d=0, fs_hz=FS))
    params = {'scheme': 'ls', 'fs_hz': FS, 'taps': design.taps.tolist(),
              'denominator': design.denominator.tolist(), 'provenance': {'plant': str(path)}}
    return (b, a), design, params


def target(seconds, fs=FS):
    t = np.arange(int(seconds * fs)) / fs
    return 2e-3 * np.sin(2 * np.pi * 1.3 * t) + 1e-3 * np.sin(2 * np.pi * 4.1 * t)


def test_pi_lead_is_the_benchmarks_controller_discretised_by_tustin(setup):
    _, design, _ = setup
    rng = np.random.default_rng(3)
    y = rng.standard_normal(500) * 1e-3
    m = rng.standard_normal(500) * 1e-3
    ctrl = PiLead(design)
    u = [ctrl.step(y[0])] + [ctrl.step(y[k], m[k - 1]) for k in range(1, y.size)]
    lead = signal.bilinear(*LEAD, FS)
    pi = signal.bilinear([KP, KI], [1.0, 0.0], FS)
    m_prev = np.r_[0.0, m[:-1]]
    expected = signal.lfilter(*pi, signal.lfilter(*lead, y) - m_prev)
    np.testing.assert_allclose(u, expected, rtol=1e-9, atol=1e-12)
    assert ctrl.status.state == 'fixed'


def test_pi_lead_guards_freeze_the_integrator_and_fall_back(setup):
    """Tracking on the benchmark's plant: test/test_realtime_methods.py (the graph)."""
    _, design, _ = setup
    x = target(0.5)
    ctrl = PiLead(design)
    prev = None
    for v in x:
        ctrl.step(v, prev)
        prev = 0.9 * v          # a steady 10 % error: the integrator moves
    integral = ctrl.coefficients()[2]
    assert integral != 0.0
    ctrl.flag_fault('hold')
    for v in x[:100]:
        ctrl.step(v, prev)
    assert ctrl.coefficients()[2] == integral          # frozen while the bridge holds
    ctrl.clear_fault()
    ctrl.step(x[3], float('nan'))
    assert ctrl.fallen_back and 'non-finite measurement' in ctrl.status.reason
    # the designed filter has run in parallel on every target: the fallback is bumpless
    fir = MultiChannelFilter(design.taps, design.denominator)
    for v in np.r_[x, x[:100], x[3]]:
        fir.step(np.array([v]))
    assert ctrl.step(x[4], 0.0) == pytest.approx(float(fir.step(np.array([x[4]]))[0]))


def test_pi_lead_gains_come_from_the_parameters(setup):
    from rths_compensator.adaptive import methods_from_params

    _, _, params = setup
    ctrl = methods_from_params(dict(params, method='pi_lead', pi_lead_kp=0.5,
                                    pi_lead_ki=60.0), 1)
    assert list(ctrl.coefficients()[:2]) == [0.5, 60.0]
    default = methods_from_params(dict(params, method='pi_lead'), 1)
    assert list(default.coefficients()[:2]) == [KP, KI]
    with pytest.raises(ValueError, match='pi_lead'):
        methods_from_params(dict(params, method='pi_lead', pi_lead_ki=-1.0), 1)


def test_pi_lead_is_a_feedback_method_not_a_compensator():
    assert METHODS.entry('pi_lead').feedback and not METHODS.entry('pi_lead').adaptive
    assert 'pi_lead' not in compensator_names()
    assert set(compensator_names()) == {'fir', 'rls_fir', 'ats', 'amb'}


def _loop(core, plant_ba, x, drop_disp=(), drop_meas=()):
    """Step ``core`` on ``x`` with a plant; returns commands by step (lost ones absent)."""
    plant = MultiChannelFilter(*plant_ba)
    commands, filled = {}, 0
    for k, v in enumerate(x):
        if k in drop_disp:
            continue
        res = core.step(k, [v])
        assert res is not None, k
        filled += res.filled
        commands[k] = float(res.arrays[0][0])
        y = float(plant.step(np.array([commands[k]]))[0])
        if k not in drop_meas:
            out = core.measure(k, [y], [commands[k]])
            assert out is None   # realtime: nothing ever waits
    return commands, filled


@pytest.mark.parametrize('method', ['fir', 'rls_fir', 'ats', 'amb', 'pi_lead'])
def test_realtime_core_equals_lockstep_on_time_and_survives_losses(setup, method):
    plant_ba, _, params = setup
    params = dict(params, method=method)
    if method == 'pi_lead':   # the paper's gains suit the benchmark's plant, not this 3-pole
        params.update(pi_lead_kp=0.5, pi_lead_ki=60.0)
    x = target(2.5)
    lock = CompensatorCore(params)
    plant = MultiChannelFilter(*plant_ba)
    expected, result = [], lock.step(0, [x[0]])
    for k in range(x.size):
        expected.append(float(result.arrays[0][0]))
        y = float(plant.step(np.array([expected[-1]]))[0])
        result = lock.measure(k, [y], [expected[-1]]) if lock.adaptive else None
        if k + 1 < x.size and result is None:
            result = lock.step(k + 1, [x[k + 1]])
    rt = CompensatorCore(params, realtime=True)
    rt.warm_up()
    on_time, filled = _loop(rt, plant_ba, x)
    assert filled == 0
    assert np.array_equal([on_time[k] for k in range(x.size)], expected)
    lossy = CompensatorCore(params, realtime=True)
    drops = set(range(100, x.size, 97))
    commands, filled = _loop(lossy, plant_ba, x, drop_disp=drops,
                             drop_meas=set(range(50, x.size, 31)))
    assert filled == len(drops)
    values = np.array(list(commands.values()))
    assert np.all(np.isfinite(values))
    assert np.max(np.abs(values)) < 10 * np.max(np.abs(expected))
    if lossy.adaptive:
        assert lossy.filter.status.state != 'fallback', lossy.filter.status
