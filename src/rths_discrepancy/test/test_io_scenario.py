"""The io scenario and its linear baseline.

Synthetic systems with a known answer, and the cascaded-tanks benchmark against its
published errors (real data, not in the repository).
"""

import numpy as np
import pytest
from scipy import signal

from rths_common.testing import require_data
from rths_discrepancy import devsets, iodisc, ioreport, linear, unseen
from rths_discrepancy import signals as sg


def _second_order(fn_hz, zeta, fs):
    w = 2 * np.pi * fn_hz
    return signal.cont2discrete(([w * w], [1, 2 * zeta * w, w * w]), 1 / fs, method='zoh')[:2]


def _record(u, y, fs, name='r'):
    return {'u': u, 'y': np.column_stack([y]), 'fs': fs, 'source': name, 'outputs': ['y'],
            'input': 'u'}


def _noise(n, seed, fs, band):
    rng = np.random.default_rng(seed)
    return signal.sosfilt(signal.butter(4, band, fs=fs, output='sos'), rng.standard_normal(n))


def test_spectral_derivative_is_exact_inside_the_band_of_a_non_periodic_record():
    fs, n = 610.0, 6000
    t = np.arange(n) / fs
    x = 1e-3 * np.sin(2 * np.pi * 97.3 * t + 0.4)      # near fs / 6: central differences lose 9 %
    v = sg.spectral_derivative(x, fs, 1, fc=150.0)
    a = sg.spectral_derivative(x, fs, 2, fc=150.0)
    mid = slice(n // 10, -n // 10)
    w = 2 * np.pi * 97.3
    assert np.max(np.abs(v[mid] - w * 1e-3 * np.cos(w * t[mid] + 0.4))) < 0.02 * w * 1e-3
    assert np.max(np.abs(a[mid] + w * w * x[mid])) < 0.03 * w * w * 1e-3
    cd = np.gradient(x, 1 / fs)
    assert np.max(np.abs(cd[mid])) < 0.93 * w * 1e-3       # the loss the spectral one avoids


def test_period_found_only_in_a_repeating_record():
    u = np.tile(_noise(500, 1, 100.0, 20.0), 4)
    assert sg.period(u) == 500
    assert sg.period(_noise(2000, 2, 100.0, 20.0)) is None


def test_linear_baseline_recovers_an_oversampled_resonance_in_any_units():
    fs = 2000.0
    num, den = _second_order(12.0, 0.03, fs)
    u = 1e4 * _noise(40000, 3, fs, 30.0)                 # volts x 1e4: no SI magnitudes
    y = 7e-6 * signal.lfilter(num.ravel(), den, u) + 3.0
    y += 0.002 * np.std(y) * np.random.default_rng(4).standard_normal(y.size)
    m = linear.fit([(u[:30000], y[:30000])], fs)
    assert m.q > 1                                      # decimated to the band
    e = (m.simulate(u) - y)[30000:]                     # held-out tail, no restart transient
    assert np.sqrt(np.mean(e ** 2)) / np.std(y[30000:]) < 0.03


def test_linear_baseline_is_at_the_noise_floor_of_a_lightly_damped_shaker_record():
    # A continuous single-degree-of-freedom system (DOP853, unseen's own generator) driven
    # by a broadband random-phase force, volts with an offset, 0.5 % output noise: the
    # held-out later part is simulated after the input before it.  From rest, the
    # start-up transient of the 3 %-damped mode was scored as the baseline's error (and
    # chose its orders): NRMSE 0.28 where the noise is 0.0064.
    case = {'name': 'sdof', 'scenario': 'io', 'effect': 'linear', 'fs': 1234.5, 'n': 4000,
            'fn_hz': 59.6, 'excitation': 'random', 'zeta': 0.03, 'units': 'volts',
            'noise': 0.005, 'size': 0.5, 'offset': True, 'seed': 11}
    rec, clean = unseen.io_case(case)
    res = iodisc.run([rec], plots=False)
    p = res['per_output']['y']
    k = int(iodisc.TRAIN_FRACTION * rec['u'].size)
    y = rec['y'][k:, 0]
    floor = np.sqrt(np.mean((y - clean[k:]) ** 2)) / np.std(y)
    assert res['effect'] == 'none'
    assert p['nrmse_baseline'] <= 1.3 * floor
    assert p['nrmse_baseline'] <= 1.2 * p['nrmse_reference']
    base = linear.fit([(rec['u'][:k], rec['y'][:k, 0])], rec['fs'])
    cold = iodisc.simulate(base, {'u': rec['u'][k:], 'level': 0.0})
    assert iodisc._nrmse(y, cold) > 5 * floor          # the transient a cold start scores


def test_a_block_must_beat_the_arx_reference_where_the_baseline_falls_short_of_it():
    # The judged unseen battery's io_linear_0 of seed 20261204 (unseen's generator, its
    # parameters as drawn): a linear SDOF in mm and kN with an offset.  The decimated
    # baseline (held out 0.0054) falls short of the plain ARX reference (0.0019, the
    # noise); a cubic law refitted by output error beat the baseline (0.0031) and was
    # named cubic_stiffness.  Over the reference it gains nothing held out.
    case = {'name': 'io_linear_0', 'scenario': 'io', 'effect': 'linear', 'fs': 1000.0,
            'n': 10000, 'fn_hz': 11.745559503769517, 'excitation': 'random',
            'zeta': 0.06675232418557385, 'units': 'mm_kN', 'noise': 0.0016212888089133834,
            'size': 0.709849647704409, 'offset': True, 'seed': 1020457470}
    rec, _ = unseen.io_case(case)
    res = iodisc.run([rec], plots=False)
    p = res['per_output']['y']
    assert p['nrmse_reference'] < 0.5 * p['nrmse_baseline']     # the shortfall is there
    assert res['effect'] == 'none'
    confirm = p['heldout_confirmation']
    assert confirm is None or (confirm['versus_reference'] and not confirm['confirmed'])


def test_io_names_no_effect_on_a_linear_system():
    fs = 200.0
    num, den = _second_order(5.0, 0.05, fs)
    u = _noise(12000, 5, fs, 15.0)
    y = signal.lfilter(num.ravel(), den, u)
    y += 0.01 * np.std(y) * np.random.default_rng(6).standard_normal(y.size)
    res = iodisc.run([_record(u, y, fs)], plots=False)
    assert res['effect'] == 'none'


def test_io_names_saturation_where_the_output_plateaus():
    fs = 50.0
    u = _noise(8000, 7, fs, 2.0)
    y = signal.lfilter([0.05], [1, -0.95], u)
    lim = 0.6 * np.max(y)
    y = np.minimum(y, lim) + 0.002 * np.std(y) * np.random.default_rng(8).standard_normal(y.size)
    res = iodisc.run([_record(u, y, fs)], plots=False)
    assert 'saturation' in res['effect'].split('+')
    p = res['per_output']['y']
    assert p['nrmse_after'] < 0.8 * p['nrmse_baseline']
    assert p['parameters']['upper_limit'] == pytest.approx(lim, rel=0.05)


def test_io_names_a_saturation_that_clips_only_the_highest_peaks():
    # unseen's shaker test with its output clipped at 85 % of its peak (size 0.31): a
    # broadband response reaches there in a few hundred samples of 10000 (fewer than the
    # 0.5 % the plateau once needed: named static_output_nonlinearity, gap 0.24)
    case = {'name': 'clip', 'scenario': 'io', 'effect': 'output_clipping', 'fs': 5000.0,
            'n': 10000, 'fn_hz': 120.0, 'excitation': 'random', 'zeta': 0.05,
            'units': 'volts', 'noise': 0.002, 'size': 0.31, 'offset': False, 'seed': 5}
    rec, clean = unseen.io_case(case)
    res = iodisc.run([rec], plots=False)
    p = res['per_output']['y']
    assert 'saturation' in res['effect'].split('+')
    k = int(iodisc.TRAIN_FRACTION * rec['u'].size)
    y = rec['y'][k:, 0]
    floor = np.sqrt(np.mean((y - clean[k:]) ** 2)) / np.std(y)
    assert p['nrmse_after'] ** 2 - floor ** 2 < 0.5 * (p['nrmse_baseline'] ** 2 - floor ** 2)


def test_io_names_amplitude_dependent_stiffness_across_levels():
    fs = 200.0
    recs = []
    for i, (amp, fn) in enumerate(((1.0, 6.0), (3.0, 5.6), (5.0, 5.2))):   # softening joint
        num, den = _second_order(fn, 0.03, fs)
        u = amp * _noise(12000, 10 + i, fs, 15.0)
        y = signal.lfilter(num.ravel(), den, u)
        recs.append(_record(u, y + 0.005 * np.std(y) * np.random.default_rng(i).standard_normal(
            y.size), fs, f'level{i}'))
    for r in recs:
        r['yj'], r['level'] = r['y'][:, 0], iodisc.level(r)
    base = linear.fit([(r['u'], r['yj']) for r in recs], fs)
    cand = iodisc.amplitude_dependent(base, recs)
    assert cand.params['relative_frequency_shift'] < -0.05     # 6.0 -> 5.2 Hz
    assert 'amplitude_dependent_stiffness' in iodisc.amplitude_names(cand.params)
    assert iodisc._mse(cand, recs) < 0.5 * iodisc._mse(base, recs)


def test_io_refuses_a_record_without_rate_or_column():
    cols = {'u': np.arange(300.0), 'y': np.arange(300.0)}
    with pytest.raises(ValueError, match='--fs'):
        iodisc.records_from_columns(cols, 'u', ['y'], source='a.csv')
    with pytest.raises(ValueError, match="no column 'z'"):
        iodisc.records_from_columns(cols, 'u', ['z'], fs=10.0, source='a.csv')


def _data_dir(name):
    """Return the data directory holding ``name`` (skip without it; fail in CI)."""
    return str(require_data(name).parent)


def test_cascaded_tanks_against_the_published_errors():
    # Cascaded tanks benchmark (Schoukens, Mattsson, Wigren, Noel 2016; data via
    # forgi86/dynonet, MIT repository): test-record RMSE [V] of the simulated level.
    # Published (Math. Probl. Eng. 2021, 6613425, Table 2, column "MSE (validation)", read
    # as the benchmark's e_RMS): BLA 0.7574, Volterra 3rd degree with transient removal
    # 0.5400, PNLSS-I 0.4498.  The benchmark
    # document names a hard (overflow) saturation with weakly nonlinear outflows.
    train, test = devsets.cascaded_tanks(_data_dir('cascaded_tanks'))
    res = iodisc.run(train, test, plots=False)
    row = devsets.compare('cascaded_tanks', res)
    assert row['baseline_rmse'] <= 1.2 * 0.7574
    assert 'saturation' in res['effect'].split('+') and row['named_effect_matches_paper']
    assert row['after_rmse'] <= 1.5 * 0.4498
    assert row['after_rmse'] < row['baseline_rmse']


def test_bouc_wen_benchmark_names_hysteresis_and_beats_the_published_errors():
    # Bouc-Wen benchmark (Noel, Schoukens 2016; simulated by its authors; data via
    # forgi86/dynonet, MIT repository): RMSE [m] of the simulated displacement on the
    # multisine test period.  Published (dynoNet, Forgione and Piga, arXiv:2006.02250,
    # section 5.2): dynoNet 4.52e-5, PNLSS (Esfahani et al. 2017) 1.87e-5, NFIR (Belz et
    # al. 2017) 16.3e-5.  The law of the benchmark (its section 2): m = 2 kg, c = 10 N s/m,
    # k = 5e4 N/m, alpha = 5e4 N/m, beta = 1e3 1/m, gamma = 0.8, delta = -1.1, nu = 1.
    train, test = devsets.bouc_wen(_data_dir('bouc_wen'))
    res = iodisc.run(train, test, plots=False)
    row = devsets.compare('bouc_wen', res)
    assert res['effect'] == 'hysteresis' and row['named_effect_matches_paper']
    assert row['after_rmse'] <= 1.5 * 1.87e-5
    p = res['per_output']['displacement']['parameters']
    assert p['m'] == pytest.approx(2.0, rel=0.05) and p['k'] == pytest.approx(5e4, rel=0.05)
    assert p['theta'] == pytest.approx(5e4, rel=0.05)
    # the direction terms are beta delta and beta gamma of z = alpha w
    assert p['a1'] == pytest.approx(-1.1e3, rel=0.1) and p['a2'] == pytest.approx(800, rel=0.1)


def test_io_rate_from_a_time_column():
    t = np.arange(400) / 610.35
    cols = {'time_s': np.round(t, 6), 'u': np.sin(t * 40), 'y': np.cos(t * 40)}
    rec = iodisc.records_from_columns(cols, 'u', ['y'], time_col='time_s', source='a.csv')
    assert rec['fs'] == pytest.approx(610.35, rel=1e-4)
    with pytest.raises(ValueError, match='disagrees'):
        iodisc.records_from_columns(cols, 'u', ['y'], fs=400.0, time_col='time_s',
                                    source='a.csv')


def test_quiet_silences_the_io_scenario_progress(tmp_path, monkeypatch, capsys):
    from rths_bringup.cli import main
    fs = 100.0
    u = _noise(3000, 11, fs, 10.0)
    y = signal.lfilter([0.1], [1, -0.9], u)
    path = tmp_path / 'r.csv'
    np.savetxt(path, np.column_stack([u, y]), delimiter=',', header='volt,level', comments='')
    args = ['discrepancy', '--scenario', 'io', '--measured', str(path), '--input', 'volt',
            '--output', 'level', '--fs', '100', '--out', str(tmp_path / 'o')]
    monkeypatch.setenv('RTHS_PROGRESS', 'log')          # restored after the test
    assert main(args + ['--quiet']) == 0
    out = capsys.readouterr()
    assert out.err == '' and 'effect:' in out.out


def test_report_names_a_diverged_candidate_instead_of_printing_its_error():
    # A candidate whose free run is unstable (the tanks' backlash block reached 4e144)
    # reads as diverged, not as an error size; an unfitted one as '-'.
    assert ioreport.nrmse_cell(4.1e144) == 'diverged (free run unstable)'
    assert ioreport.nrmse_cell(float('nan')) == 'diverged (free run unstable)'
    assert ioreport.nrmse_cell(None) == '-'
    assert ioreport.nrmse_cell(0.21634) == '0.2163'


def _scored(name, mse):
    cand = iodisc.Candidate(name, lambda u, lev: u, 3, {})
    return {'mse': mse, 'ic': 1000.0 * np.log(mse), 'cand': cand}


def test_a_loop_must_clearly_beat_the_limit_on_a_record_that_plateaus():
    # a Bouc-Wen variable saturates smoothly and imitated the plateau of a clipped
    # output (issue 25, unseen io_output_clipping: named hysteresis, gap 0.09): on a
    # record with a saturation reading the loop must remove half of its error
    scores = {'hysteresis/bouc-wen-output-error': _scored('hysteresis', 0.8),
              'saturation': _scored('saturation', 1.0),
              'static_output_nonlinearity+saturation':
                  _scored('static_output_nonlinearity+saturation', 0.95)}
    best = 'hysteresis/bouc-wen-output-error'
    assert iodisc._loop_or_limit(scores, best) == 'static_output_nonlinearity+saturation'
    scores[best] = _scored('hysteresis', 0.4)      # a real loop: half the limit's error
    assert iodisc._loop_or_limit(scores, best) == best
    del scores['saturation'], scores['static_output_nonlinearity+saturation']
    scores[best] = _scored('hysteresis', 0.99)     # no plateau: the criterion decides
    assert iodisc._loop_or_limit(scores, best) == best
