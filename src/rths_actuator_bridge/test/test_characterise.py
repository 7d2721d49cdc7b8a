"""DTM characterisation (seed section 5.1.2): recovers known c_d, k_d from noisy records."""

import json

import numpy as np
import pytest
from scipy.signal import lsim

from rths_actuator_bridge import characterise as ch
from rths_actuator_bridge.cli import main
from rths_numerical.dtm import TABLE4, TABLE4_PRINTED, DTMParameters
from rths_numerical.signals import blwn

FS = 512.0


def _record(params: DTMParameters, seed, band=8.0, seconds=40.0, noise=0.03):
    """Return a base acceleration BLWN and the eq. 47 response, both with 3 % (RMS) noise."""
    rng = np.random.default_rng(seed)
    acc = blwn(seconds, FS, band, 3.0, rng, taper_s=1.0)
    t = np.arange(len(acc)) / FS
    _, rel, _ = lsim(([-params.m_d], [params.m_d, params.c_d, params.k_d]), acc, t)
    acc_n = acc + noise * np.std(acc) * rng.standard_normal(len(acc))
    rel_n = rel + noise * np.std(rel) * rng.standard_normal(len(rel)) + 2e-4   # + LVDT offset
    return ch.DTMRecord(acc_n, rel_n, FS, f'seed {seed}')


def test_recovers_known_parameters_from_noisy_data():
    true = DTMParameters(m_d=200.0, c_d=800.0, k_d=60000.0)     # not a Table 4 entry
    fit = ch.fit_dtm(_record(true, 1), m_d=true.m_d)
    assert fit.c_d == pytest.approx(true.c_d, rel=0.03)
    assert fit.k_d == pytest.approx(true.k_d, rel=0.01)
    assert fit.zeta == pytest.approx(true.zeta, rel=0.03)
    assert fit.f_n == pytest.approx(true.f_n, rel=0.01)


def test_joint_fit_of_several_records_is_at_least_as_good():
    true = DTMParameters(m_d=258.35, c_d=300.0, k_d=80000.0)
    recs = [_record(true, s, band=b, seconds=20.0, noise=0.1) for s, b in
            ((2, 4.0), (3, 6.0), (4, 10.0))]
    joint = ch.fit_dtm(recs, m_d=true.m_d)
    singles = [ch.fit_dtm(r, m_d=true.m_d) for r in recs]
    err_joint = abs(joint.c_d - true.c_d)
    assert err_joint <= max(abs(s.c_d - true.c_d) for s in singles)
    assert joint.c_d == pytest.approx(true.c_d, rel=0.05)


@pytest.mark.parametrize('name, kind, band', [('valve3', 'blwn', 5.0), ('novalve', 'chirp', 5.0),
                                              ('valve1', 'sine', 2.5)])
def test_table4_from_simulated_shake_table_tests(name, kind, band):
    """Full plant (actuator, table, DTM, sensor noise): Table 4 within 3 % (issue 4)."""
    rec = ch.simulated_test(name, kind, band, 0.2, seed=11, duration_s=30.0)
    fit = ch.fit_dtm(rec, m_d=TABLE4[name].m_d)
    assert fit.c_d == pytest.approx(TABLE4[name].c_d, rel=0.03)
    assert fit.k_d == pytest.approx(TABLE4[name].k_d, rel=0.03)
    zeta_pct, f_n = TABLE4_PRINTED[name]
    assert 100 * fit.zeta == pytest.approx(zeta_pct, rel=0.03)
    assert fit.f_n == pytest.approx(f_n, rel=0.03)


def test_transfer_function_is_eq47():
    p = TABLE4['valve4']
    h = ch.transfer_function(p.m_d, p.c_d, p.k_d, [0.0, p.f_n])
    assert h[0] == pytest.approx(-p.m_d / p.k_d)
    # at resonance the phase is -90 deg relative to DC sign (pure damping term)
    assert abs(h[1].real) < 1e-3 * abs(h[1])


def test_cli_csv_plot_and_json(tmp_path, capsys):
    true = DTMParameters(m_d=258.35, c_d=491.6, k_d=80810.0)
    paths = []
    for s in (5, 6):
        rec = _record(true, s, seconds=20.0)
        path = tmp_path / f'rec{s}.csv'
        ch.write_csv(path, rec, force=np.zeros(len(rec.rel_disp)))
        paths.append(path)
    out = tmp_path / 'fit.json'
    png = tmp_path / 'tf.png'
    argv = ['characterise-dtm', '--mass-kg', '258.35', '--plot', str(png), '--out', str(out)]
    for p in paths:
        argv += ['--csv', str(p)]
    assert main(argv) == 0
    data = json.loads(out.read_text())
    assert data['combined']['c_d'] == pytest.approx(491.6, rel=0.03)
    assert len(data['per_record']) == 2
    assert png.stat().st_size > 10000
    assert 'zeta' in capsys.readouterr().out


def test_cli_errors_name_the_column_and_fix(tmp_path, capsys):
    bad = tmp_path / 'bad.csv'
    bad.write_text('time,accel,rel_disp\n' + '\n'.join(f'{i / 100},0,0' for i in range(100)))
    assert main(['characterise-dtm', '--csv', str(bad)]) == 2
    err = capsys.readouterr().err
    assert 'base_accel' in err and 'bad.csv' in err
    assert main(['characterise-dtm']) == 2
    assert '--csv' in capsys.readouterr().err


def test_bench_dtm_json_layout_on_a_tiny_grid(tmp_path, monkeypatch, capsys):
    """``rths bench dtm`` on 2 BLWNs + 2 chirps of one configuration (the full run is the CLI)."""
    monkeypatch.setattr(ch, 'BENCH_BLWNS', [(5, 0.2), (10, 0.05)])
    monkeypatch.setattr(ch, 'BENCH_CHIRPS', [(5, 0.1), (10, 0.05)])
    out = tmp_path / 'dtm.json'
    assert main(['bench', 'dtm', '--out', str(out), '--configs', 'valve4', '--blwn-s', '20',
                 '--chirp-s', '20']) == 0
    data = json.loads(out.read_text())
    assert set(data['valve4']) == {'c_d', 'k_d', 'zeta', 'f_n'}
    assert data['valve4']['c_d'] == pytest.approx(TABLE4['valve4'].c_d, rel=0.03)
    per = data['details']['configurations']['valve4']['per_record']
    assert per['blwn']['n'] == 2 and per['chirp']['n'] == 2
    assert data['details']['all_within_tolerance'] is True
