"""Simultaneous N x N identification (rths_compensator.multichannel; rths identify --channels).

The test plant is a coupled 2 x 2 discrete plant in the form of the maRTHS control plant
(rths_common/data/marths.json): each input has its own denominator (its own poles, shared by
both outputs), one slow pole, a one-sample delay, and ~15 % coupling off the diagonal.  A
shared-denominator multi-input ARX cannot represent it without bias; the state-space fit
must recover its transfer matrix from one test with both inputs excited at once.
"""

import json
import math

import numpy as np
import pytest
from scipy import signal
import yaml

from rths_common.testing import run_command
from rths_compensator import cli
from rths_compensator import multichannel as mc

FS = 1024.0
# column j: denominator a_j (poles 0.985 and 0.90 / 0.95 +- 0.1j); element (i, j):
# z^-1 (1 - zero z^-1) scaled to the static gain of the maRTHS plant's element (0.864,
# 0.131 / 0.140, 0.926); the 0.97 zero nearly cancels the slow pole, as 3 Hz vs 3.5 Hz there
A_COL = [np.poly([0.985, 0.90]), np.real(np.poly([0.95 + 0.1j, 0.95 - 0.1j]))]
DC = [[0.864, 0.131], [0.140, 0.926]]
ZERO = [[0.5, 0.97], [0.3, 0.6]]
B = [[np.array([0.0, 1.0, -ZERO[i][j]]) * DC[i][j] * A_COL[j].sum() / (1 - ZERO[i][j])
      for j in range(2)] for i in range(2)]
NOISE = 0.0124   # the maRTHS sensor noise [mm]: sqrt(1.5e-7 x 1024)


def _true_resp(f):
    out = np.empty((np.size(f), 2, 2), complex)
    for i in range(2):
        for j in range(2):
            out[:, i, j] = signal.freqz(B[i][j], A_COL[j], worN=f, fs=FS)[1]
    return out


def _plant(u, rng=None):
    """Return the outputs of the plant, with the sensor noise when ``rng`` is given."""
    y = np.zeros_like(u)
    for i in range(2):
        for j in range(2):
            y[:, i] += signal.lfilter(B[i][j], A_COL[j], u[:, j])
    return y if rng is None else y + NOISE * rng.standard_normal(y.shape)


def _tests(kind, rng, seconds=10.0, n=3):
    out = []
    for _ in range(n):
        u = mc.excitation(kind, 2, seconds, FS, 40.0, 3.0, rng)
        out.append((u, _plant(u, rng)))
    return out


def test_excitations_are_uncorrelated_and_scaled():
    rng = np.random.default_rng(1)
    ms = mc.excitation('multisine', 3, 4.0, FS, 40.0, 2.0, rng, taper_s=0.0)
    assert ms.shape == (4096, 3)
    assert np.allclose(np.max(np.abs(ms), axis=0), 2.0)
    # disjoint lines: exactly orthogonal over the record
    gram = ms.T @ ms
    assert np.max(np.abs(gram - np.diag(np.diag(gram)))) < 1e-9 * np.max(np.diag(gram))
    spec = np.abs(np.fft.rfft(ms, axis=0))
    f = np.fft.rfftfreq(4096, 1 / FS)
    assert np.all(spec[f > 40.5] < 1e-9 * spec.max())
    bl = mc.excitation('blwn', 2, 20.0, FS, 40.0, 3.0, rng)
    corr = np.corrcoef(bl.T)[0, 1]
    assert abs(corr) < 0.05 and np.allclose(np.max(np.abs(bl), axis=0), 3.0)
    with pytest.raises(ValueError, match='use one of blwn, multisine'):
        mc.excitation('chirp', 2, 1.0, FS, 40.0, 1.0)
    with pytest.raises(ValueError, match='lines'):
        mc.excitation('multisine', 4, 0.002, FS, 1.0, 1.0)


@pytest.mark.parametrize('kind', mc.EXCITATIONS)
def test_simultaneous_identification_recovers_the_transfer_matrix(kind):
    rng = np.random.default_rng(7)
    tests = _tests(kind, rng)
    model = mc.identify_multichannel(tests[:2], tests[2:], FS, n_max=8, horizon=20)
    # the true minimal order is 4 (two inputs, two poles each)
    assert model.order >= 4 and model.is_stable()
    grid = {r['order']: r for r in model.selection['grid']}
    assert grid[1]['fit'] > 3 * grid[model.order]['fit']
    true_dc = _true_resp([0.0])[0].real
    diag = np.abs(np.diag(true_dc))[:, None]
    # static gains within 1 % of the output's own (diagonal) gain
    assert np.max(np.abs(model.dc_gain() - true_dc) / diag) < 0.01
    # frequency response over the excited band within 2 % of the output's diagonal gain
    f = np.linspace(0.0, 40.0, 81)
    h, t = model.freq_resp(f), _true_resp(f)
    scale = np.max(np.abs(np.stack([t[:, 0, 0], t[:, 1, 1]], axis=1)), axis=0)[:, None]
    assert np.max(np.abs(h - t), axis=0).max() > 0          # a fit, not the plant itself
    assert np.max(np.max(np.abs(h - t), axis=0) / scale) < 0.02
    # the simulated output of a fresh test matches its noise-free response
    u = mc.excitation(kind, 2, 5.0, FS, 40.0, 3.0, rng)
    clean = _plant(u)
    assert np.sqrt(np.mean((model.simulate(u) - clean) ** 2)) < 0.03 * np.std(clean)


def test_cross_coupling_report_matches_the_plant():
    rng = np.random.default_rng(3)
    tests = _tests('blwn', rng)
    model = mc.identify_multichannel(tests[:2], tests[2:], FS, n_max=6, horizon=20)
    rep = mc.cross_coupling(model, 40.0)
    t = _true_resp(np.linspace(0.0, 40.0, 400))
    true_dc = t[0].real
    true_peak = np.max(np.abs(t), axis=0)
    assert rep['band_hz'] == 40.0
    assert np.allclose(rep['dc_gain'], true_dc, atol=0.01 * true_dc.max())
    assert np.allclose(rep['peak_gain'], true_peak, rtol=0.02)
    want = np.abs(true_dc) / np.abs(np.diag(true_dc))[:, None]
    assert np.allclose(rep['dc_rel'], want, atol=0.005)
    assert rep['dc_rel'][0][0] == 1.0
    want = true_peak / np.diag(true_peak)[:, None]
    assert np.allclose(rep['peak_rel'], want, rtol=0.02)


def test_a_shared_denominator_arx_is_biased_where_the_state_space_is_not():
    """The reverted approach: y_i = (B_i1 u_1 + B_i2 u_2) / A_i by equation-error LS."""
    rng = np.random.default_rng(11)
    (u, y), = _tests('blwn', rng, seconds=20.0, n=1)
    na = nb = 4
    k0 = max(na, nb)
    rows = [np.concatenate([-y[k - na:k, 0][::-1], u[k - nb:k, 0][::-1], u[k - nb:k, 1][::-1]])
            for k in range(k0, len(u))]
    theta = np.linalg.lstsq(np.array(rows), y[k0:, 0], rcond=None)[0]
    a = np.r_[1.0, theta[:na]]
    arx_dc = np.array([theta[na:na + nb].sum(), theta[na + nb:].sum()]) / a.sum()
    true_dc = _true_resp([0.0])[0].real[0]
    (u2, y2), (u3, y3) = _tests('blwn', rng, seconds=20.0, n=2)
    model = mc.identify_multichannel([(u, y), (u2, y2)], [(u3, y3)], FS, orders=[4],
                                     horizon=20)
    ss_err = np.max(np.abs(model.dc_gain()[0] - true_dc)) / true_dc[0]
    arx_err = np.max(np.abs(arx_dc - true_dc)) / true_dc[0]
    assert ss_err < 0.01 < arx_err


def test_bad_records_are_refused():
    rng = np.random.default_rng(2)
    tests = _tests('blwn', rng, seconds=2.0, n=2)
    with pytest.raises(ValueError, match='training and validation'):
        mc.identify_multichannel(tests, [], FS)
    u, y = tests[1]
    with pytest.raises(ValueError, match='same channels'):
        mc.identify_multichannel(tests[:1], [(u, y[:, :1])], FS)
    with pytest.raises(ValueError, match='raise horizon'):
        mc.identify_multichannel(tests[:1], tests[1:], FS, n_max=50, horizon=10)
    assert math.isfinite(mc.validation_error(
        mc.identify_multichannel(tests[:1], tests[1:], FS, n_max=4, horizon=10),
        tests[1:])[0])


# ----------------------------------------------------------------------------- rths identify
# ``rths identify --channels N``: the same plant, as a lab's CSV in millimetres (header units)
# with both actuators excited at once by uncorrelated BLWN (3 mm, 0-40 Hz) and the maRTHS
# sensor noise; its off-diagonal gain is 15.2 % / 15.1 % of the diagonal at DC.

def _run(argv):
    return run_command(cli.register, argv)


@pytest.fixture(scope='module')
def record(tmp_path_factory):
    """Write a 30 s CSV, header in mm: time, command_1, command_2, measured_1, measured_2."""
    rng = np.random.default_rng(4)
    u = mc.excitation('blwn', 2, 30.0, FS, 40.0, 3.0, rng)
    y = _plant(u, rng)
    path = tmp_path_factory.mktemp('mimo') / 'excitation.csv'
    t = np.arange(u.shape[0]) / FS
    np.savetxt(path, np.column_stack([t, u, y]), delimiter=',', fmt='%.10g', comments='',
               header='time [s],command_1 [mm],command_2 [mm],measured_1 [mm],measured_2 [mm]')
    return path


@pytest.fixture(scope='module')
def identified(record, tmp_path_factory):
    """Return ``(plant file, printed lines)`` of ``rths identify --channels 2`` of the record."""
    import contextlib
    import io

    out = tmp_path_factory.mktemp('ident') / 'plant2.yaml'
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        assert _run(['identify', '--csv', str(record), '--channels', '2',
                     '--out', str(out)]) == 0
    return out, printed.getvalue()


def test_two_actuators_identified_with_their_coupling(identified):
    out, printed = identified
    tmp_path = out.parent
    doc = yaml.safe_load(out.read_text())
    model = mc.model_from_dict(doc, str(out))
    assert doc['kind'] == 'state_space' and doc['n_channels'] == 2 and doc['units'] == 'm'
    assert model.is_stable() and 4 <= model.order < 12     # the true minimal order is 4
    # millimetres read as such: the static gains are dimensionless, within 1 % of the
    # diagonal gain of the true plant (as test_multichannel on the same construction)
    dc = np.array(DC)
    diag = np.abs(np.diag(dc))[:, None]
    assert np.max(np.abs(model.dc_gain() - dc) / diag) < 0.01
    f = np.linspace(0.0, 40.0, 81)
    err = np.max(np.abs(model.freq_resp(f) - _true_resp(f)), axis=0)
    assert np.max(err / diag) < 0.03
    # the cross-coupling, in the plant file, the JSON and the printed lines
    report = json.loads((tmp_path / 'plant2_identification.json').read_text())
    cc = report['cross_coupling']
    assert cc == doc['cross_coupling']
    true_rel = dc / np.diag(dc)[:, None]
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


def test_design_of_the_identified_plant_writes_a_coupled_fir(identified, tmp_path, capsys):
    """``rths design`` of the N x N plant file: ``coupled_taps``, and a prediction that holds.

    Checked on the TRUE plant over 0-20 Hz: command 2 moves actuator 1 by up to 8.9 times
    actuator 1's own response (the lightly damped poles of column 2 near 17 Hz, where
    actuator 1's own gain is low); with the coupled FIR (the defaults: n = 48, fc 30 Hz,
    the maRTHS benchmark's) it is 20 % (on 2026-11-28: 20.2 / 11.3 %), and the figures
    ``rths design`` predicts on the identified model are the true plant's within 3 points.
    """
    from rths_compensator.design import target_lowpass
    from rths_compensator.params import coupled_taps_of, load_compensator_params
    plant, _ = identified
    comp = tmp_path / 'coupled.yaml'
    assert _run(['design', '--plant', str(plant), '--out', str(comp)]) == 0
    printed = capsys.readouterr().out
    params = load_compensator_params(comp)
    flat = coupled_taps_of(params)
    assert flat is not None and flat.size == 2 * 2 * 48
    f = np.linspace(0.0, 20.0, 200)
    true = _true_resp(f)
    loop = mc.coupled_response(true, flat.reshape(2, 2, 48), f, FS)

    def coupling(m):
        diag = np.abs(np.stack([m[:, 0, 0], m[:, 1, 1]], axis=1))
        return np.max(np.abs(np.stack([m[:, 0, 1], m[:, 1, 0]], axis=1)) / diag, axis=0)
    plant_coupling, left = coupling(true), coupling(loop)
    assert plant_coupling[0] > 5.0 and np.all(left < 0.25) and left[0] < plant_coupling[0] / 20
    gain, a_l = target_lowpass(4, 100.0, FS)
    ell = gain / np.polyval(a_l[::-1], np.exp(-2j * np.pi * f / FS))
    tracking = max(np.max(np.abs(loop[:, i, i] - ell) / np.abs(ell)) for i in range(2))
    prov = params['provenance']
    assert abs(prov['residual_coupling_pct'] - 100 * np.max(left)) < 3.0
    assert abs(prov['tracking_error_pct'] - 100 * tracking) < 3.0
    assert prov['plant_coupling_pct'] == pytest.approx(100 * plant_coupling[0], rel=0.05)
    assert f"cross-coupling up to {prov['residual_coupling_pct']:.2f} %" in printed
    with pytest.raises(ValueError, match='--scheme belongs to one actuator.s design'):
        _run(['design', '--plant', str(plant), '--scheme', 'ls', '--out', str(comp)])
    with pytest.raises(ValueError, match='--option n_taps=4: give KEY=VALUE with KEY one of'):
        _run(['design', '--plant', str(plant), '--option', 'n_taps=4', '--out', str(comp)])


def test_identify_reads_the_bag_of_a_two_actuator_run(tmp_path, capsys):
    """``--bag`` of a run with two actuators: each step's applied commands and strokes."""
    from rths_common import cdr, topics
    from rths_common.bagio import BagWriter

    rng = np.random.default_rng(9)
    u = mc.excitation('multisine', 2, 12.0, FS, 40.0, 3e-3, rng)      # [m]
    y = _plant(u) + NOISE * 1e-3 * rng.standard_normal(u.shape)      # the noise in m
    t0 = 1_800_000_000_000_000_000
    with BagWriter(tmp_path / 'bag', topics.LOOP_TOPICS,
                   run_info={'kind': 'rths', 'fs_hz': FS}) as bag:
        for k in range(u.shape[0]):
            stamp = t0 + int(k * 1e9 / FS)
            bag.write(topics.MEASUREMENT, stamp, cdr.pack_step_arrays(
                stamp, k, u[k], y[k], np.zeros(2)))
    out = tmp_path / 'plant2.yaml'
    assert _run(['identify', '--bag', str(tmp_path / 'bag'), '--channels', '2', '--no-plot',
                 '--out', str(out)]) == 0
    model = mc.model_from_dict(yaml.safe_load(out.read_text()))
    dc = np.array(DC)
    assert np.max(np.abs(model.dc_gain() - dc) / np.abs(np.diag(dc))[:, None]) < 0.01
    assert 'command 2 -> actuator 1: 15.' in capsys.readouterr().out
    with pytest.raises(ValueError, match='bag holds 2 actuator channels, not 3; give '
                                         '--channels 2'):
        _run(['identify', '--bag', str(tmp_path / 'bag'), '--channels', '3',
              '--out', str(tmp_path / 'p3.yaml')])


# ----------------------------------------------------------------- adaptive correction
def _run_correction(corr, gains, lags, seconds=20.0, amplitude=1.0, noise=0.002, seed=3):
    """Drive ``corr`` (batch 1, one channel per gain) through channels y = g v (lag).

    Channel c answers the corrected target v with ``y(k) = g_c v(k - lags_c)``, where lag 0
    stands for a design that predicts the sample (``2 v(k-1) - v(k-2)``, as the coupled FIR
    makes ``y(k)`` follow ``v(k)``) and lag 1 for one sample behind it.  Returns the RMS
    tracking error per channel over the last 5 s, relative to the target's.
    """
    rng = np.random.default_rng(seed)
    n = int(seconds * FS)
    t = np.arange(n) / FS
    target = amplitude * (np.sin(2 * np.pi * 1.1 * t) + 0.5 * np.sin(2 * np.pi * 2.7 * t + 1))
    nc = len(gains)
    v_hist = np.zeros((3, nc))
    err = []
    for k in range(n):
        pred = np.where(np.asarray(lags) == 0, 2 * v_hist[0] - v_hist[1], v_hist[0])
        y = np.asarray(gains) * pred + noise * rng.standard_normal(nc)
        v = corr.step(np.full((1, nc), target[k]), None if k == 0 else y[None])[0]
        v_hist = np.roll(v_hist, 1, axis=0)
        v_hist[0] = v
        if k >= n - 5 * int(FS):
            err.append(target[k] - y)
    return np.std(np.array(err), axis=0) / np.std(target[-5 * int(FS):])


def test_adaptive_correction_learns_each_channels_gain_and_time_shift():
    corr = mc.AdaptiveCorrection(1, 2, FS, excitation=0.1)
    rel = _run_correction(corr, gains=[0.8, 1.0], lags=[0, 1])
    a = corr.a[0]
    # channel 0: 20 % short in gain -> a0 = 1 / 0.8; channel 1: one sample late -> lead 1/fs
    assert a[0, 0] == pytest.approx(1.25, rel=0.03)
    assert a[0, 1] == pytest.approx(0.0, abs=2e-4)
    assert a[1, 0] == pytest.approx(1.0, rel=0.03)
    assert a[1, 1] == pytest.approx(1.0 / FS, rel=0.25)
    # without the correction the errors are 20 % and ~1.3 %; with it near the noise (0.25 %)
    fixed = _run_correction(mc.AdaptiveCorrection(1, 2, FS, excitation=1e9),
                            gains=[0.8, 1.0], lags=[0, 1])
    assert np.all(fixed[0] > 0.19) and fixed[1] > 2 * rel[1]
    assert np.all(rel < 0.006)
    assert not corr.fallen_back.any()


def test_adaptive_correction_freezes_below_the_excitation_and_falls_back_on_a_bad_channel():
    quiet = mc.AdaptiveCorrection(1, 1, FS, excitation=2.0)
    _run_correction(quiet, gains=[0.8], lags=[0], seconds=5.0)
    assert quiet.a[0, 0].tolist() == [1.0, 0.0]        # target RMS ~0.8 < 2: frozen
    wrong = mc.AdaptiveCorrection(1, 1, FS, excitation=0.1)
    _run_correction(wrong, gains=[-1.0], lags=[0], seconds=5.0)
    assert wrong.fallen_back[0, 0]                      # error 200 % > 30 %: the design alone
    assert wrong.a[0, 0].tolist() == [1.0, 0.0]
