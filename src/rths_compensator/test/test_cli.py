"""The rths identify / design / compensate / unstable-zeros commands, end to end (tiny sizes)."""

import time

import numpy as np
import pytest
from scipy import signal

from rths_common.columns import read_columns
from rths_common.testing import run_command
from rths_compensator import cli
from rths_compensator.identification import load_plant
from rths_compensator.params import load_compensator_params

FS = 256.0


def _run(argv):
    return run_command(cli.register, argv)


@pytest.fixture(scope='module')
def run_csv(tmp_path_factory):
    """Return a 60 s identification run of a known 2nd-order, unit-DC-gain ARX plant."""
    rng = np.random.default_rng(0)
    a = np.array([1.0, -1.6, 0.68])
    b = np.array([0.02, 0.06])  # zero at z = -3: non-minimum phase
    n = int(60 * FS)
    u = rng.standard_normal(n) * 1e-3
    y = signal.lfilter(b, a, u) + signal.lfilter([1.0], a, 1e-7 * rng.standard_normal(n))
    path = tmp_path_factory.mktemp('run') / 'ident.csv'
    t = np.arange(n) / FS
    np.savetxt(path, np.column_stack([t, u, y]), delimiter=',', header='time,command,measured',
               comments='', fmt='%.12g')
    return path, a, b


def test_identify_design_compensate_chain(tmp_path, run_csv, capsys):
    csv_path, a, b = run_csv
    plant_path = tmp_path / 'plant.yaml'
    assert _run(['identify', '--csv', str(csv_path), '--out', str(plant_path),
                 '--na-max', '3', '--nb-max', '3']) == 0
    plant = load_plant(plant_path)
    assert plant.fs_hz == pytest.approx(FS)          # read from the time column
    assert (plant.na, plant.nb) == (2, 2)
    np.testing.assert_allclose(plant.a, a, atol=1e-3)

    comp_path = tmp_path / 'config' / 'compensator.yaml'
    assert _run(['design', '--plant', str(plant_path), '--scheme', 'ls', '--taps', '20',
                 '--fc', '20', '--epsilon', '0.01', '--out', str(comp_path)]) == 0
    params = load_compensator_params(comp_path)
    prov = params['provenance']
    assert params['scheme'] == 'ls' and prov['n_taps'] == 20 and prov['fc_hz'] == 20.0
    assert abs(prov['predicted_delay_ms']) < 1.0
    assert prov['plant'].endswith('plant.yaml')

    out_path = tmp_path / 'out.csv'
    assert _run(['compensate', '--params', str(comp_path), '--csv', str(csv_path),
                 '--out', str(out_path)]) == 0
    cols = read_columns(out_path, ('time', 'command', 'compensated'))
    ref = signal.lfilter(params['taps'], params['denominator'], cols['command'])
    np.testing.assert_allclose(cols['compensated'], ref, rtol=1e-8,
                               atol=1e-9 * np.max(np.abs(ref)))


@pytest.mark.parametrize('scheme', ['inverse', 'mff', 'npz', 'zpetc', 'zmetc'])
def test_design_comparison_schemes(tmp_path, run_csv, scheme):
    plant_path = tmp_path / 'plant.yaml'
    _run(['identify', '--csv', str(run_csv[0]), '--out', str(plant_path),
          '--na-max', '2', '--nb-max', '2'])
    out = tmp_path / 'c.yaml'
    assert _run(['design', '--plant', str(plant_path), '--scheme', scheme, '--band', '10',
                 '--out', str(out)]) == 0
    assert load_compensator_params(out)['scheme'] == scheme


def test_design_refuses_infeasible_and_writes_nothing(tmp_path, run_csv):
    plant_path = tmp_path / 'plant.yaml'
    _run(['identify', '--csv', str(run_csv[0]), '--out', str(plant_path),
          '--na-max', '2', '--nb-max', '2'])
    out = tmp_path / 'c.yaml'
    with pytest.raises(ValueError, match='epsilon'):
        _run(['design', '--plant', str(plant_path), '--scheme', 'ls', '--taps', '3',
              '--fc', '100', '--epsilon', '1e-6', '--out', str(out)])
    assert not out.exists()


def test_identify_reports_missing_column(tmp_path):
    bad = tmp_path / 'bad.csv'
    bad.write_text('time,command\n0,0\n0.1,1\n')
    with pytest.raises(ValueError, match='measured'):
        _run(['identify', '--csv', str(bad), '--out', str(tmp_path / 'p.yaml')])


def test_unstable_zeros_command(tmp_path, capsys):
    png = tmp_path / 'zeros.png'
    assert _run(['unstable-zeros', '--plot', str(png), '--fs-max', '200']) == 0
    out = capsys.readouterr().out
    assert '3pole' in out and '41.' in out and '42.' in out
    assert png.stat().st_size > 1000


@pytest.fixture(scope='module')
def damped_zero_plant(tmp_path_factory):
    """plant.yaml: the 3-pole model times a lightly damped zero pair (|z| = 0.995, 150 Hz)."""
    from rths_compensator.identification import ArxModel, save_plant
    from rths_compensator.plants import discrete_actuator
    fs = 1024.0
    b, a = discrete_actuator('3pole', fs)
    r, th = 0.995, 2 * np.pi * 150.0 / fs
    b = np.convolve(b, [1.0, -2 * r * np.cos(th), r * r])
    model = ArxModel(a=a, b=b / (np.sum(b) / np.sum(a)), fs_hz=fs)
    path = tmp_path_factory.mktemp('plant') / 'plant.yaml'
    save_plant(path, model)
    return path, model


def _max_pole(den):
    return float(np.max(np.abs(np.roots(den)))) if len(den) > 1 else 0.0


def test_design_zero_tol_reproduces_design_fir_and_is_recorded(tmp_path, damped_zero_plant):
    """--zero-tol 0.98 (the bench's BENCH_ZERO_TOL) keeps the 0.995 pair out of B+*."""
    from rths_compensator import design as dsg
    from rths_compensator.bench import BENCH_ZERO_TOL
    plant_path, model = damped_zero_plant
    common = ['design', '--plant', str(plant_path), '--scheme', 'wls', '--taps', '50',
              '--fc', '32', '--epsilon', '0.01']
    plain, tol = tmp_path / 'plain.yaml', tmp_path / 'tol.yaml'
    assert _run(common + ['--out', str(plain)]) == 0
    assert _run(common + ['--zero-tol', str(BENCH_ZERO_TOL), '--out', str(tol)]) == 0
    p_plain, p_tol = load_compensator_params(plain), load_compensator_params(tol)
    assert p_plain['provenance']['zero_tol'] == 1.0
    assert p_tol['provenance']['zero_tol'] == BENCH_ZERO_TOL
    assert _max_pole(p_plain['denominator']) == pytest.approx(0.995, abs=1e-6)
    assert _max_pole(p_tol['denominator']) < BENCH_ZERO_TOL
    ref = dsg.design_default(model, scheme='wls', n_taps=50, fc_hz=32.0, epsilon=0.01,
                             zero_tol=BENCH_ZERO_TOL)
    np.testing.assert_allclose(p_tol['taps'], ref.taps, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(p_tol['denominator'], ref.denominator, rtol=1e-9)


def test_design_auto_passes_zero_tol(tmp_path, damped_zero_plant, monkeypatch):
    from rths_compensator import design as dsg
    plant_path, _ = damped_zero_plant
    seen = []
    design_fir = dsg.design_fir

    def spy(*args, **kwargs):
        seen.append(kwargs.get('zero_tol'))
        return design_fir(*args, **kwargs)

    monkeypatch.setattr(dsg, 'design_fir', spy)
    out = tmp_path / 'auto.yaml'
    assert _run(['design', '--plant', str(plant_path), '--auto', '--bandwidth', '10',
                 '--zero-tol', '0.97', '--epsilon', '0.01', '--out', str(out)]) == 0
    assert seen and set(seen) == {0.97}
    params = load_compensator_params(out)
    if params['scheme'] in ('ls', 'wls', 'mm'):
        assert params['provenance']['zero_tol'] == 0.97
        assert _max_pole(params['denominator']) < 0.97


@pytest.mark.parametrize('extra, match', [
    (['--scheme', 'npz', '--zero-tol', '0.98'], 'FIR schemes'),
    (['--scheme', 'ls', '--zero-tol', '1.5'], 'zero-tol'),
    (['--scheme', 'ls', '--zero-tol', '0'], 'zero-tol')])
def test_design_refuses_bad_zero_tol(tmp_path, damped_zero_plant, extra, match):
    out = tmp_path / 'c.yaml'
    with pytest.raises(ValueError, match=match):
        _run(['design', '--plant', str(damped_zero_plant[0]), '--out', str(out)] + extra)
    assert not out.exists()


@pytest.mark.parametrize('digits', [6, 10])
def test_identified_rate_is_exact_and_the_taps_launch(tmp_path, digits):
    # a 1024 Hz run written with `digits` significant digits used to give fs_hz 1023.54 or
    # 1024.000524 Hz, and the loop's preflight then refused the designed taps
    from rths_compensator.params import check_sampling_rate
    rng = np.random.default_rng(1)
    n = 20 * 1024
    u = rng.standard_normal(n) * 1e-3
    y = signal.lfilter([0.05, 0.1], [1.0, -1.2, 0.35], u)
    csv_path = tmp_path / 'ident.csv'
    np.savetxt(csv_path, np.column_stack([np.arange(n) / 1024.0, u, y]), delimiter=',',
               header='time,command,measured', comments='', fmt=f'%.{digits}g')
    plant_path, comp_path = tmp_path / 'plant.yaml', tmp_path / 'compensator.yaml'
    assert _run(['identify', '--csv', str(csv_path), '--out', str(plant_path),
                 '--na-max', '2', '--nb-max', '2', '--record-s', '5']) == 0
    assert load_plant(plant_path).fs_hz == 1024.0
    assert _run(['design', '--plant', str(plant_path), '--scheme', 'ls', '--taps', '10',
                 '--fc', '20', '--out', str(comp_path)]) == 0
    params = load_compensator_params(comp_path)
    assert params['fs_hz'] == 1024.0
    check_sampling_rate(params, 1024.0, str(comp_path), 'fs_hz of numerical.yaml')


def test_design_and_launch_take_a_rate_to_its_printed_digits(tmp_path, run_csv):
    from rths_compensator.identification import save_plant
    from rths_compensator.params import check_sampling_rate
    plant_path = tmp_path / 'plant.yaml'
    _run(['identify', '--csv', str(run_csv[0]), '--out', str(plant_path),
          '--na-max', '2', '--nb-max', '2'])
    plant = load_plant(plant_path)
    plant.fs_hz = FS * (1 + 2e-9)                     # a plant.yaml of an older identify
    save_plant(plant_path, plant, {})
    out = tmp_path / 'c.yaml'
    assert _run(['design', '--plant', str(plant_path), '--scheme', 'ls', '--taps', '10',
                 '--fc', '20', '--out', str(out)]) == 0
    assert load_compensator_params(out)['fs_hz'] == FS
    check_sampling_rate({'fs_hz': 1024.000524}, 1024.0, 'c.yaml', 'loop')
    with pytest.raises(ValueError, match='designed for 1024.01 Hz but the loop runs at 1024 Hz'):
        check_sampling_rate({'fs_hz': 1024.01}, 1024.0, 'c.yaml', 'loop')


@pytest.fixture(scope='module')
def lab_csv(tmp_path_factory):
    """Return a DAQ-like run: 2000 Hz, 9 ms actuator delay, 0.5 % sensor noise (synthetic)."""
    from rths_compensator._blas import limit_blas_threads
    from rths_compensator.plants import actuator_poles
    from rths_compensator.synthetic import SyntheticActuator, identification_record
    limit_blas_threads(1)
    act = SyntheticActuator(actuator_poles('3pole'), 9e-3, 2000.0)
    t, u, y = identification_record(act, 30.0, 40.0, 0.005, 0.5, np.random.default_rng(8))
    path = tmp_path_factory.mktemp('lab') / 'lab.csv'
    np.savetxt(path, np.column_stack([t, u, y]), delimiter=',',
               header='time,command,measured', comments='', fmt='%.10g')
    plant = path.parent / 'plant.yaml'
    assert _run(['identify', '--csv', str(path), '--out', str(plant)]) == 0
    return path, plant, act


def test_identify_defaults_print_save_and_plot_the_fit(lab_csv, capsys):
    import yaml
    _, plant, act = lab_csv
    doc = yaml.safe_load(plant.read_text())
    val = doc['selection']['validation']
    assert 0.4 < val['nrmse_pct'] < 0.7
    assert doc['selection']['record']['kind'] == 'csv'
    assert (plant.parent / 'plant_fit.png').stat().st_size > 10000
    assert abs(doc['d'] - act.model().d) <= 4


def test_design_defaults_predict_and_stay_within_limits(lab_csv, tmp_path, capsys):
    from rths_compensator.synthetic import tracking, tracking_signals
    _, plant, act = lab_csv
    out = tmp_path / 'c.yaml'
    assert _run(['design', '--plant', str(plant), '--out', str(out)]) == 0
    text = capsys.readouterr().out
    assert 'compensator alone: gain peak' in text and 'loop on the record' in text
    params = load_compensator_params(out)
    prov = params['provenance']
    assert params['scheme'] == 'wls' and prov['n_taps'] == 400 and prov['fc_hz'] == 10.0
    assert prov['limits_exceeded'] == ''
    true_pct = tracking(act, params['taps'], params['denominator'],
                        tracking_signals(2000.0)['noise'])['tracking_pct']
    assert true_pct < 0.5
    # predicted from the record's held-out part alone, without the model, for the reference
    # (the record's motion in 0-10 Hz): within 0.2 % of the true actuator's tracking of it
    from rths_common.columns import read_columns
    from rths_compensator.assessment import reference_signal
    measured = read_columns(lab_csv[0], ('measured',))['measured']
    reference, _ = reference_signal(2000.0, 10.0, measured)
    true_ref = tracking(act, params['taps'], params['denominator'], reference)['tracking_pct']
    assert prov['record_tracking_pct'] == pytest.approx(true_ref, abs=0.2)


def test_design_beyond_the_limits_is_refused_unless_forced(lab_csv, tmp_path):
    _, plant, _ = lab_csv
    out = tmp_path / 'c.yaml'
    # fc beyond the record's 40 Hz excitation, the seed's objective: a 127 dB compensator
    argv = ['design', '--plant', str(plant), '--scheme', 'wls', '--fc', '60', '--taps',
            '400', '--epsilon', '0.05', '--gain-weight', '0', '--out', str(out)]
    with pytest.raises(ValueError, match='design refused: the command for the reference'):
        _run(argv)
    assert not out.exists()
    assert _run(argv + ['--force']) == 0
    assert load_compensator_params(out)['provenance']['limits_exceeded']


def test_identify_reads_a_daq_file_by_column_names_and_units(lab_csv, tmp_path, capsys):
    """The lab's own CSV: ``Time (ms), Cmd (mm), Disp (mm)``, its columns named on the line."""
    import yaml

    from rths_common.columns import read_columns
    cols = read_columns(lab_csv[0], ('time', 'command', 'measured'))
    daq = tmp_path / 'daq.csv'
    np.savetxt(daq, np.column_stack([cols['time'] * 1e3, cols['command'] * 1e3,
                                     cols['measured'] * 1e3])[:30000],
               delimiter=',', header='Time (ms),Cmd (mm),Disp (mm)', comments='', fmt='%.9g')
    plant = tmp_path / 'plant.yaml'
    with pytest.raises(ValueError, match='missing column.*--columns'):
        _run(['identify', '--csv', str(daq), '--out', str(plant)])
    assert _run(['identify', '--csv', str(daq), '--out', str(plant), '--no-plot',
                 '--columns', 'Time,Cmd,Disp', '--na-max', '3', '--nb-max', '4']) == 0
    err = capsys.readouterr().err
    assert "time = column 'Time' in ms (header)" in err
    assert "measured = column 'Disp' in mm (header)" in err
    doc = yaml.safe_load(plant.read_text())
    assert doc['fs_hz'] == 2000.0 and abs(doc['b'][0] + sum(doc['b'][1:])) < 1.0
    assert doc['selection']['record']['columns'] == {'time': 'Time', 'command': 'Cmd',
                                                     'measured': 'Disp'}
    # by index, units from the options (a header-less file)
    bare = tmp_path / 'bare.csv'
    np.savetxt(bare, np.loadtxt(daq, delimiter=',', skiprows=1), delimiter=',', fmt='%.9g')
    assert _run(['identify', '--csv', str(bare), '--out', str(plant), '--no-plot',
                 '--columns', '0,1,2', '--time-unit', 'ms', '--length-unit', 'mm',
                 '--na-max', '3', '--nb-max', '4']) == 0
    assert "time = column '#0' in ms (option)" in capsys.readouterr().err
    assert yaml.safe_load(plant.read_text())['fs_hz'] == 2000.0


def test_identify_refuses_command_and_measured_swapped(tmp_path, run_csv):
    # the swapped record fit as well and gave the inverse plant without a word
    from rths_compensator.causality import response_lag_s
    cols = read_columns(run_csv[0], ('time', 'command', 'measured'))
    assert response_lag_s(cols['command'], cols['measured'], FS) > 0
    swapped = tmp_path / 'swapped.csv'
    np.savetxt(swapped, np.column_stack([cols['time'], cols['measured'], cols['command']]),
               delimiter=',', header='time,command,measured', comments='', fmt='%.12g')
    with pytest.raises(ValueError, match=r'swapped.csv: the measured signal leads the command '
                                         r'by [\d.]+ ms .* the columns look swapped'):
        _run(['identify', '--csv', str(swapped), '--out', str(tmp_path / 'plant.yaml'),
              '--na-max', '2', '--nb-max', '2'])
    assert not (tmp_path / 'plant.yaml').exists()


def test_more_taps_than_the_loop_can_compute_are_refused_up_front(tmp_path, run_csv):
    # 200 000 taps were accepted, and a 2 000 000-tap loop hung 135 s before failing
    from rths_compensator.params import MAX_COEFFICIENT_RATE, check_sampling_rate
    plant_path = tmp_path / 'plant.yaml'
    _run(['identify', '--csv', str(run_csv[0]), '--out', str(plant_path),
          '--na-max', '2', '--nb-max', '2'])
    t0 = time.monotonic()
    with pytest.raises(ValueError, match=r'--taps 1000000: 1000000 filter coefficients at 256 Hz '
                                         r'are 2.56e\+08 multiply-adds .*; design fewer taps'):
        _run(['design', '--plant', str(plant_path), '--scheme', 'ls', '--taps', '1000000',
              '--fc', '20', '--out', str(tmp_path / 'c.yaml')])
    assert time.monotonic() - t0 < 5.0 and not (tmp_path / 'c.yaml').exists()
    most = int(MAX_COEFFICIENT_RATE // 1024.0)
    params = {'scheme': 'ls', 'fs_hz': 1024.0, 'denominator': [1.0]}
    check_sampling_rate(dict(params, taps=[0.0] * (most - 1)), 1024.0, 'c.yaml', 'loop')
    with pytest.raises(ValueError, match=f'at most {most} coefficients at 1024 Hz'):
        check_sampling_rate(dict(params, taps=[0.0] * 200_000), 1024.0, 'c.yaml', 'loop')
