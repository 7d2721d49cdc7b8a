"""The rths identify / design / compensate / unstable-zeros commands, end to end (tiny sizes)."""

import argparse

import numpy as np
import pytest
from scipy import signal

from rths_compensator import cli
from rths_compensator.identification import load_plant
from rths_compensator.io import read_csv_columns
from rths_compensator.params import load_compensator_params

FS = 256.0


def _run(argv):
    parser = argparse.ArgumentParser(prog='rths')
    commands = parser.add_subparsers(dest='command', required=True)
    bench = commands.add_parser('bench')
    benches = bench.add_subparsers(dest='bench', required=True)
    cli.register(commands, benches)
    args = parser.parse_args(argv)
    return args.func(args)


@pytest.fixture(scope='module')
def run_csv(tmp_path_factory):
    """A 60 s identification run of a known 2nd-order, unit-DC-gain ARX plant."""
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
    assert params['scheme'] == 'ls' and params['n_taps'] == 20 and params['fc_hz'] == 20.0
    assert abs(params['predicted_delay_ms']) < 1.0
    assert params['plant'].endswith('plant.yaml')

    out_path = tmp_path / 'out.csv'
    assert _run(['compensate', '--params', str(comp_path), '--csv', str(csv_path),
                 '--out', str(out_path)]) == 0
    cols = read_csv_columns(out_path, ('time', 'command', 'compensated'))
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


def test_identify_bag_without_bagio(tmp_path, monkeypatch):
    import builtins
    real_import = builtins.__import__

    def fake_import(name, *args, **kwargs):
        if name.startswith('rths_bringup.bagio'):
            raise ImportError(name)
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, '__import__', fake_import)
    with pytest.raises(ValueError, match='export a CSV'):
        _run(['identify', '--bag', str(tmp_path), '--out', str(tmp_path / 'p.yaml')])


def test_unstable_zeros_command(tmp_path, capsys):
    png = tmp_path / 'zeros.png'
    assert _run(['unstable-zeros', '--plot', str(png), '--fs-max', '200']) == 0
    out = capsys.readouterr().out
    assert '3pole' in out and '41.' in out and '42.' in out
    assert png.stat().st_size > 1000
