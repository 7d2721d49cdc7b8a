"""``rths identify --channels N``: the N x N plant and its cross-coupling from one record.

The plant is a coupled 2 x 2 discrete plant in the form of the maRTHS control plant
(rths_common/data/marths.json; the same construction as test_multichannel.py): each command
has its own denominator, a one-sample delay, and the static gains of the maRTHS plant's
transfer matrix (0.864, 0.131 / 0.140, 0.926, ``fcn_build_uncert_plant.m``), so the
off-diagonal gain is 15.2 % / 15.1 % of the diagonal at DC.  The record is a lab's CSV in
millimetres with both actuators excited at once by uncorrelated BLWN (3 mm, 0-40 Hz) and
the benchmark's sensor noise.
"""

import argparse
import json

import numpy as np
import pytest
from scipy import signal
import yaml

from rths_compensator import cli
from rths_compensator import multichannel as mc

FS = 1024.0
A_COL = [np.poly([0.985, 0.90]), np.real(np.poly([0.95 + 0.1j, 0.95 - 0.1j]))]
DC = np.array([[0.864, 0.131], [0.140, 0.926]])
ZERO = [[0.5, 0.97], [0.3, 0.6]]
B = [[np.array([0.0, 1.0, -ZERO[i][j]]) * DC[i][j] * A_COL[j].sum() / (1 - ZERO[i][j])
      for j in range(2)] for i in range(2)]
NOISE_MM = 0.0124   # the maRTHS sensor noise: sqrt(1.5e-7 x 1024) [mm]


def _run(argv):
    parser = argparse.ArgumentParser(prog='rths')
    commands = parser.add_subparsers(dest='command', required=True)
    bench = commands.add_parser('bench')
    benches = bench.add_subparsers(dest='bench', required=True)
    cli.register(commands, benches)
    args = parser.parse_args(argv)
    return args.func(args)


def _true_resp(f):
    out = np.empty((np.size(f), 2, 2), complex)
    for i in range(2):
        for j in range(2):
            out[:, i, j] = signal.freqz(B[i][j], A_COL[j], worN=f, fs=FS)[1]
    return out


@pytest.fixture(scope='module')
def record(tmp_path_factory):
    """Write a 30 s CSV, header in mm: time, command_1, command_2, measured_1, measured_2."""
    rng = np.random.default_rng(4)
    u = mc.excitation('blwn', 2, 30.0, FS, 40.0, 3.0, rng)
    y = np.zeros_like(u)
    for i in range(2):
        for j in range(2):
            y[:, i] += signal.lfilter(B[i][j], A_COL[j], u[:, j])
    y += NOISE_MM * rng.standard_normal(y.shape)
    path = tmp_path_factory.mktemp('mimo') / 'excitation.csv'
    t = np.arange(u.shape[0]) / FS
    np.savetxt(path, np.column_stack([t, u, y]), delimiter=',', fmt='%.10g', comments='',
               header='time [s],command_1 [mm],command_2 [mm],measured_1 [mm],measured_2 [mm]')
    return path


def test_two_actuators_identified_with_their_coupling(record, tmp_path, capsys):
    out = tmp_path / 'plant2.yaml'
    assert _run(['identify', '--csv', str(record), '--channels', '2', '--out', str(out)]) == 0
    printed = capsys.readouterr().out
    doc = yaml.safe_load(out.read_text())
    model = mc.model_from_dict(doc, str(out))
    assert doc['kind'] == 'state_space' and doc['n_channels'] == 2 and doc['units'] == 'm'
    assert model.is_stable() and 4 <= model.order < 12     # the true minimal order is 4
    # millimetres read as such: the static gains are dimensionless, within 1 % of the
    # diagonal gain of the true plant (as test_multichannel on the same construction)
    diag = np.abs(np.diag(DC))[:, None]
    assert np.max(np.abs(model.dc_gain() - DC) / diag) < 0.01
    f = np.linspace(0.0, 40.0, 81)
    err = np.max(np.abs(model.freq_resp(f) - _true_resp(f)), axis=0)
    assert np.max(err / diag) < 0.03
    # the cross-coupling, in the plant file, the JSON and the printed lines
    report = json.loads((tmp_path / 'plant2_identification.json').read_text())
    cc = report['cross_coupling']
    assert cc == doc['cross_coupling']
    true_rel = DC / np.diag(DC)[:, None]
    assert np.allclose(cc['dc_rel'], true_rel, atol=0.005)
    assert abs(cc['dc_rel_max'] - true_rel[0, 1]) < 0.005          # 0.131 / 0.864 = 15.2 %
    # over the band the coupling peaks higher (command 2's lightly damped poles)
    peak = np.max(np.abs(_true_resp(np.linspace(0.0, cc['band_hz'], 400))), axis=0)
    assert np.allclose(cc['peak_rel'], peak / np.diag(peak)[:, None], rtol=0.03)
    assert 35.0 <= cc['band_hz'] <= 45.0                          # the BLWN's band
    assert max(report['validation']['nrmse_pct']) < 5.0
    assert report['input_correlation_max'] < 0.1 and not report['warnings']
    assert 'command 2 -> actuator 1: 15.' in printed and 'largest:' in printed
    assert (tmp_path / 'plant2_fit.png').stat().st_size > 10_000


def test_correlated_commands_are_warned(tmp_path, capsys):
    """One actuator's command a copy of the other's: the coupling cannot be separated."""
    rng = np.random.default_rng(8)
    u1 = mc.excitation('blwn', 1, 8.0, FS, 30.0, 0.003, rng)[:, 0]
    u = np.column_stack([u1, 0.9 * u1 + 0.1 * mc.excitation('blwn', 1, 8.0, FS, 30.0,
                                                            0.003, rng)[:, 0]])
    y = np.column_stack([signal.lfilter([0, 0.2], [1, -0.8], u[:, i]) for i in range(2)])
    path = tmp_path / 'rths_run.csv'
    np.savetxt(path, np.column_stack([np.arange(u.shape[0]) / FS, u, y]), delimiter=',',
               header='time,command_1,command_2,measured_1,measured_2', comments='')
    assert _run(['identify', '--csv', str(path), '--channels', '2', '--order-max', '4',
                 '--no-plot', '--out', str(tmp_path / 'p.yaml')]) == 0
    assert 'WARNING: commands 1 and 2 correlate by 0.9' in capsys.readouterr().out


def test_a_missing_or_misnamed_column_is_refused_naming_it(record, tmp_path):
    out = tmp_path / 'p.yaml'
    bad = tmp_path / 'bad.csv'
    text = record.read_text().splitlines()
    text[0] = text[0].replace('measured_2 [mm]', 'measured 2 [mm]')
    bad.write_text('\n'.join(text[:3000]) + '\n')
    with pytest.raises(ValueError, match=r'missing column\(s\) measured_2 \(header has .*'
                                         r'measured 2\)') as err:
        _run(['identify', '--csv', str(bad), '--channels', '2', '--out', str(out)])
    assert '\n' not in str(err.value) and not out.exists()
    with pytest.raises(ValueError, match='--channels 3 needs 7 columns, time, command_1'):
        _run(['identify', '--csv', str(record), '--channels', '3', '--columns', '0,1,2,3,4',
              '--out', str(out)])
    with pytest.raises(ValueError, match='missing column.*command_3'):
        _run(['identify', '--csv', str(record), '--channels', '3', '--out', str(out)])
    with pytest.raises(ValueError, match='--na-max belongs to one actuator'):
        _run(['identify', '--csv', str(record), '--channels', '2', '--na-max', '4',
              '--out', str(out)])
    with pytest.raises(ValueError, match='--order-max belongs to --channels N'):
        _run(['identify', '--csv', str(record), '--order-max', '4', '--out', str(out)])
    with pytest.raises(ValueError, match='--channels 0'):
        _run(['identify', '--csv', str(record), '--channels', '0', '--out', str(out)])
    assert not out.exists()


def test_a_plant_file_is_read_exactly(tmp_path):
    model = mc.MimoModel(np.array([[0.5]]), np.array([[1.0, 0.2]]), np.array([[1.0], [0.3]]),
                         np.zeros((2, 2)), FS)
    doc = model.to_dict()
    assert mc.model_from_dict(doc).order == 1
    with pytest.raises(ValueError, match='p.yaml: field c has the shape'):
        mc.model_from_dict(dict(doc, c=[[1.0, 2.0]]), 'p.yaml')
    with pytest.raises(ValueError, match='field b missing'):
        mc.model_from_dict({k: v for k, v in doc.items() if k != 'b'})
    with pytest.raises(ValueError, match='not an N x N plant file'):
        mc.model_from_dict({'kind': 'arx'})


def test_design_refuses_an_n_by_n_plant_in_one_line(tmp_path):
    from rths_compensator.identification import load_plant
    model = mc.MimoModel(np.array([[0.5]]), np.array([[1.0, 0.2]]), np.array([[1.0], [0.3]]),
                         np.zeros((2, 2)), FS)
    path = tmp_path / 'plant2.yaml'
    mc.save_plant(path, model, {'cross_coupling': mc.cross_coupling(model, 10.0)})
    with pytest.raises(ValueError, match='plant2.yaml: an N x N plant of 2 actuators'):
        load_plant(path)
