"""The scenarios: a run's numbers do not hang on its chunk; the SPECs reproduce the studies."""

import numpy as np

from rths_study.spec import check_spec
from rths_study.worker import evaluate_chunk


def _evaluate(spec, runs):
    return evaluate_chunk(spec.kind, spec.settings, [r.as_dict() for r in runs], spec.metrics)


def _benchmark_spec(tmp_path, controller):
    # A synthetic 1.5 s record (a 3.5 Hz burst) in a 2-column file: no data set needed.
    t = np.arange(0, 1.5, 0.01)
    record = tmp_path / 'burst.txt'
    np.savetxt(record, np.column_stack([t, 1.5 * np.sin(2 * np.pi * 3.5 * t)]))
    return check_spec({
        'study': 't', 'scenario': {'kind': 'benchmark'},
        'parameters': {'list': [{'b1': 420.0, 'k_e': 1.15e6}, {'b1': 425.0, 'k_e': 1.19e6},
                                {'b1': 431.0, 'k_e': 1.23e6}]},
        'controllers': [controller], 'records': [str(record)]})


def test_benchmark_runs_alone_equal_the_same_runs_in_a_chunk_bit_for_bit(tmp_path):
    for controller in ('example', 'fir'):
        spec = _benchmark_spec(tmp_path, controller)
        runs = spec.runs()
        together = _evaluate(spec, runs)
        assert all(r['status'] == 'ok' and not r['unstable'] for r in together), together
        for i in (0, 2):
            alone = _evaluate(spec, runs[i:i + 1])[0]
            assert [alone[m] for m in spec.metrics] == [together[i][m] for m in spec.metrics]
        # different plants give different tracking
        assert together[0]['J2'] != together[2]['J2']


def test_dtm_tuning_spec_reproduces_rths_study_dtm_tuning():
    from rths_numerical.cli import run_dtm_tuning
    ref = run_dtm_tuning(n_fn=4, n_zeta=3, duration_s=8.0, fs_hz=128.0, seed=3)
    spec = check_spec({'study': 't', 'scenario': {'kind': 'dtm-tuning', 'duration_s': 8.0,
                                                  'fs_hz': 128.0, 'signal_seed': 3},
                       'parameters': {'grid': {
                           'fn_hz': {'start': 0.1, 'stop': 10.0, 'num': 4},
                           'zeta': {'start': 0.005, 'stop': 0.15, 'num': 3}}}})
    rows = _evaluate(spec, spec.runs())
    for c in ('max_disp', 'max_accel', 'rms_disp', 'rms_accel'):
        np.testing.assert_allclose(np.reshape([r[c] for r in rows], (4, 3)), ref[c],
                                   rtol=1e-12)


def test_building_frequency_spec_reproduces_the_subcommand_study():
    from rths_numerical.building import building_16dof
    from rths_numerical.ground_motion import baseline_correct, ground_motion
    from rths_numerical.studies import building_frequency_study
    fs = 100.0
    ag, _, _ = baseline_correct(ground_motion('kobe', fs, 0.135, None), 1 / fs)
    ref = building_frequency_study(building_16dof(), ag, 1 / fs, [2.0, 3.0], [0.01, 0.03],
                                   'novalve')
    spec = check_spec({'study': 't', 'scenario': {'kind': 'building-frequency', 'fs_hz': fs,
                                                  'scale': 0.135, 'damper': 'novalve'},
                       'parameters': {'grid': {'f1_hz': [2.0, 3.0],
                                               'mass_ratio': [0.01, 0.03]}},
                       'records': ['kobe']})
    rows = _evaluate(spec, spec.runs())
    for c in ('max_disp', 'rms_accel'):
        np.testing.assert_allclose(np.reshape([r[c] for r in rows], (2, 2)), ref[c],
                                   rtol=1e-12)
