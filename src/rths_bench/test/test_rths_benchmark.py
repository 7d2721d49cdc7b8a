"""The RTHS benchmark problem (Silva et al. 2020): the port pinned to the published table."""

import json

import numpy as np
import pytest

from rths_bench import rths_benchmark as rb
from rths_bringup.cli import main
from rths_common.testing import require_data


def test_j1_finds_the_lag_and_criteria_vanish_for_identical_signals():
    dt = 1.0 / 4096
    t = np.arange(20000) * dt
    rng = np.random.default_rng(1)
    desired = np.sin(2 * np.pi * 2 * t) + 0.3 * np.sin(2 * np.pi * 7.3 * t) \
        + 0.05 * rng.standard_normal(t.size)
    measured = np.concatenate([np.zeros(9), desired[:-9]])
    assert rb.j1_ms(desired, measured, dt) == round(9 * dt * 1e3, 1)     # 2.2 ms
    floors = np.column_stack([desired, 2 * desired, 3 * desired])
    js = rb.criteria(desired, floors, floors, dt)
    assert all(js[name] == 0.0 for name in rb.J_NAMES)


def test_example_controller_reproduces_published_table_3():
    # Data: El Centro record ElCentroAccelNoScaling.mat of the benchmark's code package
    # (github.com/MECHS-RCN/BENCHMARKS, "RTHS code RT V23.zip"), not redistributable: the one
    # test of truth that skips in CI too (rths_common.testing.require_data), saying why. Anyone
    # with the package reproduces Table 3 by pointing RTHS_DATA_DIR at its records.
    require_data('silva2020_records')
    # Published J1-J9: Silva, Gomez, Maghareh, Dyke, Spencer (2020), "Benchmark control
    # problem for real-time hybrid simulation", MSSP 135, 106381, Table 3 (El Centro x 0.4,
    # PI + phase lead); values from the preprint in the benchmark's code package (V23).
    # Issue 13 tolerance: J1 within 0.5 ms, J2-J9 within 15 %.
    summary = rb.run_benchmark('example', n_draws=0, log=lambda msg: None)
    for case, published in rb.PUBLISHED_EXAMPLE.items():
        ours = summary['cases'][case]
        assert abs(ours['J1'] - published[0]) <= 0.5, (case, ours)
        for name, pub in zip(rb.J_NAMES[1:], published[1:], strict=True):
            assert abs(ours[name] - pub) <= 0.15 * pub, (case, name, ours[name], pub)


def test_bench_command_tiny_configuration(tmp_path):
    # A synthetic 3 s record (a 3.5 Hz burst) in a 2-column file: no data set needed.
    t = np.arange(0, 3.0, 0.02)
    acc = 1.5 * np.sin(2 * np.pi * 3.5 * t) * np.exp(-((t - 1.0) / 0.6) ** 2)
    record = tmp_path / 'burst.txt'
    np.savetxt(record, np.column_stack([t, acc]))
    out = tmp_path / 'out'
    code = main(['bench', 'rths-benchmark', '--controller', 'example', '--record', str(record),
                 '--draws', '2', '--seed', '5', '--out', str(out), '--no-plots'])
    assert code == 0
    data = json.loads((out / 'summary.json').read_text())
    assert set(data) == {'controller', 'cases', 'perturbed', 'rules'}
    assert data['controller'] == 'example'
    assert sorted(data['cases']) == ['1', '2', '3', '4']
    assert all(sorted(row) == sorted(rb.J_NAMES) for row in data['cases'].values())
    # 2 perturbed plants with every case (the benchmark: >= 20 per case)
    assert data['perturbed']['n'] == 8 and data['perturbed']['unstable'] == 0
    assert set(data['perturbed']) == {'n', 'J1_max', 'J2_max', 'J3_max', 'unstable',
                                      'n_per_case', 'by_case'}
    assert sorted(data['perturbed']['by_case']) == ['1', '2', '3', '4']
    assert all(b['n'] == 2 and b['J2_max'] is not None
               for b in data['perturbed']['by_case'].values())
    assert data['perturbed']['J2_max'] == max(b['J2_max']
                                              for b in data['perturbed']['by_case'].values())
    # the benchmark's rules on the actuator's response, checked on every run
    rules = data['rules']['perturbed']
    assert rules['stroke_m']['limit'] == 0.007 and rules['force_n']['limit'] == 8900.0
    # this burst drives floor 1 to ~16 mm: beyond the benchmark's stroke, and said so
    assert rules['stroke_m']['max'] > 0.007 and 1 <= rules['stroke_m']['runs_over'] <= 8
    assert 0 < rules['force_n']['max'] and 0 < rules['velocity_m_s']['max']
    # the PI + phase lead lags by a few ms on this plant
    assert 2.0 <= data['cases']['1']['J1'] <= 8.0
    assert (out / 'table.md').read_text().count('\n| ') >= 4


def test_missing_record_names_the_fix(tmp_path, monkeypatch):
    monkeypatch.setenv(rb.DATA_ENV, str(tmp_path))
    with pytest.raises(OSError, match='ElCentroAccelNoScaling.mat'):
        rb.record_path('elcentro')


def test_graph_params_build_the_node_cores(tmp_path, capsys):
    from rths_actuator_bridge.bridge import Bridge
    from rths_compensator.design import design_inverse
    from rths_numerical.ground_motion import read_at2
    from rths_numerical.substructure import make_substructure

    t = np.arange(0, 2.0, 0.02)
    acc = np.sin(2 * np.pi * 1.5 * t)
    path = rb.write_at2(str(tmp_path / 'r.AT2'), t, acc)
    record = read_at2(path)
    assert record.dt == 0.02 and np.allclose(record.accel, acc, rtol=1e-7, atol=1e-9)
    params = rb.graph_params('3', design_inverse(4096.0, 10.0), path, 0.4, duration_s=0.25)
    sub = make_substructure(params['numerical'])
    assert sub.n_steps == 1024 and sub.model.name == 'silva2020_case3'
    lab = Bridge()
    lab.configure(params['bridge'])
    assert lab.backend.plant.n_states == 5
    # realtime runs through the graph only: a clear error
    assert main(['bench', 'rths-benchmark', '--mode', 'realtime', '--out',
                 str(tmp_path / 'x')]) == 2
    assert 'add --via graph' in capsys.readouterr().err


@pytest.fixture(scope='module')
def designed():
    """One short identification and FIR design of the benchmark's plant (lab procedure)."""
    return rb.identify_and_design(attempts=1, record_s=5.0, log=lambda _: None)


@pytest.mark.parametrize('controller', ['example', 'rls_fir', 'ats'])
def test_graph_params_run_every_controller_in_the_compensator_core(tmp_path, controller,
                                                                   designed):
    """The benchmark's controllers as compensator-node methods, on the benchmark's plant."""
    from rths_actuator_bridge.silva2020 import FS_HZ
    from rths_compensator.core import CompensatorCore

    design, info = designed
    plant = rb.write_method_plant(controller, info, FS_HZ, str(tmp_path / 'plant.yaml'))
    params = rb.graph_params('1', design, 'r.AT2', 0.4, controller=controller,
                             plant_yaml=plant if controller != 'example' else '')
    comp = params['compensator']
    assert comp['method'] == ('pi_lead' if controller == 'example' else controller)
    core = CompensatorCore(comp)                     # the node's core builds the method
    assert core.adaptive
    if controller == 'rls_fir':                      # its plant is the FIR's design plant
        from rths_compensator.adaptive import split_fir
        from rths_compensator.identification import load_plant
        h, a_star, _ = split_fir(design, load_plant(plant))   # the taps are A* h exactly
        assert np.allclose(np.convolve(a_star, h), design.taps, atol=1e-9)


def test_worst_realtime_over_cases_takes_the_worst_and_sums_losses():
    row = {'rate_hz': 4096.0, 'deadline_miss_pct': 0.1, 'late_or_missed_pct': 0.15,
           'floor_late_pct': 0.1, 'latency_us_p99': 80.0, 'run_completed': True,
           'step_us_p99_by_node': {'bridge': 40.0, 'compensator': 20.0},
           'step_us_p50_by_node': {'bridge': 10.0, 'compensator': 5.0},
           'recorder_loss': {'/rths/command': 0, '/rths/measurement': 1}}
    other = dict(row, late_or_missed_pct=0.3, latency_us_p99=60.0, run_completed=False,
                 step_us_p99_by_node={'bridge': 30.0, 'compensator': 50.0})
    rt = rb.worst_realtime({'1': row, '2': other})
    assert list(rt)[:7] == ['rate_hz', 'deadline_miss_pct', 'late_or_missed_pct',
                            'floor_late_pct', 'latency_us_p99', 'step_us_p99_by_node',
                            'recorder_loss']
    assert rt['late_or_missed_pct'] == 0.3 and rt['latency_us_p99'] == 80.0
    assert rt['step_us_p99_by_node'] == {'bridge': 40.0, 'compensator': 50.0}
    assert rt['recorder_loss'] == {'/rths/command': 0, '/rths/measurement': 2}
    assert rt['completed'] is False and rt['cases'] == 2


def test_example_through_the_node_cores_stays_within_the_benchmark_rules(tmp_path):
    """The PI + lead (``pi_lead``) through the node cores tracks like the benchmark's loop.

    It used to stop at the first noise peak of its command (the bridge's former 5000 m/s^2
    command acceleration limit; the hold then read as a divergence, J2 > 200 %).  The
    criteria take the measurement at the start of each sample, as the benchmark does.  A
    synthetic 3 s record (a 3.5 Hz burst, 2.4 mm at floor 1): no data set needed.
    """
    from rths_actuator_bridge.silva2020 import FS_HZ, Silva2020Params
    from rths_compensator.design import design_inverse
    dt = 1.0 / FS_HZ
    t = np.arange(0, 3.0, 0.005)
    acc = 0.3 * np.sin(2 * np.pi * 3.5 * t) * np.exp(-((t - 1.2) / 0.6) ** 2)
    path = rb.write_at2(str(tmp_path / 'burst.AT2'), t, acc)
    params = rb.graph_params('1', design_inverse(FS_HZ, 10.0), path, 1.0, duration_s=3.0,
                             controller='example')
    cores = rb.run_cores(params)
    assert cores['safety_state'].max() == 0                      # no hold, no stop
    ag = cores['ag']
    ref = rb.reference_response('1', ag, dt)
    ours = rb.criteria(rb.sampled_at_start(cores['x_m']), cores['y_n'], ref, dt)
    loop = rb.run_batch([('1', Silva2020Params())], ag, rb.ExampleController(dt, 1), seed=3)
    bench = rb.criteria(loop['x_m'][0], loop['y_n'][0], ref, dt)
    assert abs(ours['J1'] - bench['J1']) <= 0.25, (ours, bench)
    for name in ('J2', 'J3'):                    # tracking: the 5 % (J1: 0.25 ms)
        assert abs(ours[name] - bench[name]) <= 0.05 * bench[name], (name, ours, bench)
    unshifted = rb.criteria(cores['x_m'], cores['y_n'], ref, dt)
    assert unshifted['J1'] < ours['J1']         # the end-of-sample record: one sample early
    assert ours['J2'] < 20.0                                      # tracks (it was > 200 %)


def test_the_numerical_substructure_at_a_quarter_rate_keeps_the_j_values(tmp_path, capsys):
    """``--rate-divisor 4``: the numerical substructure at 1024 Hz, the loop at 4096 Hz.

    fir through the node cores on a synthetic 3 s burst: J1-J9 within the issue's 5 %
    (J1 within 0.25 ms) of the single-rate run.  On El Centro x 0.4 (20 s, four cases)
    the two differed by at most 0.04 points (docs/bench/rths_benchmark_realtime/README.md).
    """
    from rths_actuator_bridge.silva2020 import FS_HZ
    from rths_compensator.design import design_inverse
    from rths_numerical.multirate import MultiRateSubstructure
    from rths_numerical.substructure import make_substructure
    dt = 1.0 / FS_HZ
    t = np.arange(0, 3.0, 0.005)
    acc = 0.3 * np.sin(2 * np.pi * 3.5 * t) * np.exp(-((t - 1.2) / 0.6) ** 2)
    path = rb.write_at2(str(tmp_path / 'burst.AT2'), t, acc)
    design = design_inverse(FS_HZ, 10.0)
    js = {}
    for n in (1, 4):
        params = rb.graph_params('2', design, path, 1.0, duration_s=3.0, rate_divisor=n)
        assert params['numerical'].get('rate_divisor', 1) == n
        assert isinstance(make_substructure(params['numerical']),
                          MultiRateSubstructure) == (n > 1)
        res = rb.run_cores(params)
        assert res['safety_state'].max() == 0 and len(res['y_n']) == len(res['x_m']) == 12288
        js[n] = rb.criteria(rb.sampled_at_start(res['x_m']), res['y_n'],
                            rb.reference_response('2', res['ag'], dt), dt)
    assert abs(js[4]['J1'] - js[1]['J1']) <= 0.25, js
    for name in rb.J_NAMES[1:]:
        assert abs(js[4][name] - js[1][name]) <= 0.05 * js[1][name], (name, js)
    # the benchmark's own loop has no numerical node to divide
    assert main(['bench', 'rths-benchmark', '--rate-divisor', '4', '--out',
                 str(tmp_path / 'x')]) == 2
    assert 'add --via cores or --via graph' in capsys.readouterr().err
