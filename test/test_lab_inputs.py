"""A lab's own building and record through ``rths run``, against an independent reference.

The building (3 storeys, written here) and the record (band-limited noise at 200 Hz,
0.2 g, written here as ``time_s,accel_g``) were not used to tune anything.  The
reference is independent of rths's code: the building plus the seed's DTM (valve4,
Table 4; frame mass 250 lb, seed 6.2) on a perfect actuator, its equations written
out below and solved by scipy.signal.lsim on the record as written.  The same run's
bag is then reviewed again (and replayed) after the model, record and config files are
deleted.
"""

import json
import shutil

import numpy as np
import pytest
from scipy import signal
import scipy.linalg as sla
import yaml

from rths_system_tests import REPO, rths

G = 9.80665
MASSES = [6000.0, 6000.0, 5000.0]
STOREY_K = [9.0e6, 8.0e6, 6.0e6]
ZETA = 0.02
DURATION_S = 8.0


def write_building(path):
    k1, k2, k3 = STOREY_K
    stiffness = [[k1 + k2, -k2, 0.0], [-k2, k2 + k3, -k3], [0.0, -k3, k3]]
    path.write_text(yaml.safe_dump({
        'name': 'lab-3storey', 'masses': MASSES, 'K': stiffness,
        'damping': {'type': 'rayleigh', 'zeta': [ZETA, ZETA], 'modes': [0, 1]},
        'interface_dofs': [0], 'output_dof': 2, 'dof_names': ['floor 1', 'floor 2', 'roof']}))
    return np.array(stiffness)


def write_record(path):
    fs = 200.0
    t = np.arange(0.0, 20.0, 1 / fs)
    b, a = signal.butter(4, [0.5 / (fs / 2), 12 / (fs / 2)], 'band')
    x = signal.filtfilt(b, a, np.random.default_rng(42).standard_normal(t.size))
    x *= np.minimum(1.0, t / 2) * np.exp(-np.maximum(0.0, t - 8.0) / 4)
    x *= 0.2 / np.max(np.abs(x))
    lines = (f'{ti:.3f},{xi:.6f}\n' for ti, xi in zip(t, x, strict=True))
    path.write_text('time_s,accel_g\n' + ''.join(lines))
    data = np.loadtxt(path, delimiter=',', skiprows=1)
    return data[:, 0], data[:, 1] * G


def reference(stiffness, t_rec, ag_rec, t_out):
    """Relative floor displacements of the building with one DTM on floor 1 (perfect actuator).

    q = (u1, u2, u3, z), z the DTM mass relative to its frame on floor 1; the frame
    (m_f) and the mass (m_d) ride on floor 1:  M q'' + C q' + K q = -M r a_g.
    """
    from rths_numerical.dtm import FRAME_MASS_KG, TABLE4  # the specimen's constants (Table 4)

    dtm = TABLE4['valve4']
    m = np.diag(MASSES)
    lam, phi = sla.eigh(stiffness, m)
    w1, w2 = np.sqrt(lam[:2])
    alpha, beta = np.linalg.solve([[1 / (2 * w1), w1 / 2], [1 / (2 * w2), w2 / 2]], [ZETA, ZETA])
    c = alpha * m + beta * stiffness
    mf, md = FRAME_MASS_KG, dtm.m_d
    big_m = np.zeros((4, 4))
    big_m[:3, :3] = m
    big_m[0, 0] += mf + md
    big_m[0, 3] = big_m[3, 0] = big_m[3, 3] = md
    big_c = sla.block_diag(c, dtm.c_d)
    big_k = sla.block_diag(stiffness, dtm.k_d)
    r = np.array([1.0, 1.0, 1.0, 0.0])
    minv = np.linalg.inv(big_m)
    a = np.block([[np.zeros((4, 4)), np.eye(4)], [-minv @ big_k, -minv @ big_c]])
    b = np.concatenate([np.zeros(4), -r])[:, None]
    c_out = np.hstack([np.eye(4), np.zeros((4, 4))])
    t_fine = np.arange(0.0, t_out[-1] + 1e-9, 1 / 4096)
    _, y, _ = signal.lsim((a, b, c_out, np.zeros((4, 1))), np.interp(t_fine, t_rec, ag_rec),
                          t_fine)
    return np.column_stack([np.interp(t_out, t_fine, y[:, i]) for i in range(3)])


def rel_rms_pct(x, ref):
    return 100.0 * np.sqrt(np.mean((x - ref) ** 2) / np.mean(ref ** 2))


def test_a_labs_building_and_csv_record_match_an_independent_reference(tmp_path):
    stiffness = write_building(tmp_path / 'building.yaml')
    t_rec, ag_rec = write_record(tmp_path / 'record.csv')
    out = tmp_path / 'out'
    proc = rths('run', '--model', tmp_path / 'building.yaml', '--record',
                tmp_path / 'record.csv', '--plant', REPO / 'config' / 'plant.yaml',
                '--duration', DURATION_S, '--out', out, timeout=900)
    text = proc.stdout
    # before the run: the record as read (first/last, duration, rate, peak) and as used
    assert 'as read:  record' in text and '4000 samples at 200 Hz' in text
    assert 'in g' in text and 'peak' in text and 'processing: scaled x 1;' in text
    assert 'scale 1, force scale 1, interface frame absolute' in text

    table = np.loadtxt(out / 'response.csv', delimiter=',', skiprows=1)
    header = (out / 'response.csv').read_text().splitlines()[0]
    assert header == 'time_s,ground_accel_m_s2,dof1_m,dof2_m,dof3_m'
    t = table[:, 0]
    assert t.size == int(DURATION_S * 1024) and t[0] == 0.0
    # the ground motion as used: on the record's own time axis, unshifted, its peak kept
    in_file = np.interp(t, t_rec, ag_rec)
    lags = range(-20, 21)
    corr = [np.dot(table[100 + k:-100 + k, 1], in_file[100:-100]) for k in lags]
    assert list(lags)[int(np.argmax(corr))] == 0
    peak_file = np.max(np.abs(ag_rec[t_rec <= DURATION_S]))
    assert np.max(np.abs(table[:, 1])) == pytest.approx(peak_file, rel=0.01)
    # floor 1 and the roof against the independent reference
    ref = reference(stiffness, t_rec, ag_rec, t)
    for col, name in ((2, 'floor 1'), (4, 'roof')):
        err = rel_rms_pct(table[:, col], ref[:, col - 2])
        peak = np.max(np.abs(table[:, col])) / np.max(np.abs(ref[:, col - 2])) - 1
        print(f'{name}: relative RMS error {err:.3f} %, peak {100 * peak:+.3f} %')
        assert err < 1.0 and abs(peak) < 0.01, name

    summary = json.loads((out / 'summary.json').read_text())
    assert summary['scale'] == 1.0 and summary['force_scale'] == 1.0
    assert summary['interface_frame'] == 'absolute' and summary['specimen'] == 'valve4'
    assert summary['input_processing'][1] == 'resampled 200 -> 1024 Hz (band-limited FFT)'
    assert [r['dof'] for r in summary['every_dof']] == ['floor 1', 'floor 2', 'roof']
    review = (out / 'review.txt').read_text()
    assert 'displacement of roof' in review and 'input processing: scaled x 1;' in review
    assert '<td>force scale</td><td>1.0</td>' in (out / 'report.html').read_text()

    # the bag alone: model, record and config files deleted, the same report
    bag = out / 'rths' / 'bag'
    for path in (tmp_path / 'building.yaml', tmp_path / 'record.csv', out / 'compensator.yaml'):
        path.unlink()
    shutil.rmtree(out / 'rths' / 'config')
    rths('review', bag, '--out', tmp_path / 'again', timeout=600)
    again = json.loads((tmp_path / 'again' / 'summary.json').read_text())
    summary.pop('run_settings')
    summary.pop('adaptive')
    assert again == summary
    replayed = rths('replay', bag, '--rate-scale', 1000, '--topics', '/rths/run_inputs',
                    '/rths/response', timeout=120).stdout
    assert 'replaying' in replayed and '/rths/run_inputs' in replayed
