"""Restoring-force scenario on records of any rate, units and band: the states' differentiator.

The synthetic record is a Duffing oscillator measured in volts at 610.35 Hz (the kind of
record an electronic benchmark circuit gives): ``m a + c v + k x + k3 x^3 = u`` driven by
random-phase multisines to 200 Hz, far above where central differences keep their gain.
Its numbers were set once from the physics (60 Hz resonance, 4 % damping, a cubic term
worth 10 % of the linear spring at three times the rms displacement) and not tuned on
the workflow's answers.
"""

import numpy as np
import pytest
from scipy import signal

from rths_discrepancy import restoring
from rths_discrepancy import signals as sg

FS = 610.35
M, ZETA, FN = 1e-5, 0.04, 60.0
K = M * (2 * np.pi * FN) ** 2
C = 2 * ZETA * 2 * np.pi * FN * M
X_RMS = 0.05                        # volts
K3 = 0.1 * K / (3 * X_RMS) ** 2     # 10 % of k x at three times the rms displacement


def _multisine(n, rng, f_max=200.0):
    f = np.fft.rfftfreq(n, 1 / FS)
    spec = np.where((f > 0) & (f <= f_max), np.exp(2j * np.pi * rng.random(f.size)), 0)
    u = np.fft.irfft(spec, n)
    return u / np.std(u)


def _duffing(u_fine, sub):
    """Midpoint (RK2) response to the input at ``2 sub`` points per sample; x at each sample."""
    h = 1 / (FS * sub)
    x = v = 0.0
    out = np.empty(u_fine.size // (2 * sub))
    for i in range(out.size):
        out[i] = x
        for j in range(2 * sub * i, 2 * sub * (i + 1), 2):
            a1 = (u_fine[j] - C * v - K * x - K3 * x ** 3) / M
            xm, vm = x + 0.5 * h * v, v + 0.5 * h * a1
            a2 = (u_fine[j + 1] - C * vm - K * xm - K3 * xm ** 3) / M
            x, v = x + h * vm, v + h * a2
    return out


def _record(realizations=2, n=8192, noise=0.002, seed=3, sub=4):
    """Concatenated multisine realizations (not periodic), force and displacement in volts.

    Each multisine is a sum of sines: the simulator reads it between the samples exactly
    (FFT interpolation of the periodic realization), so the record has no hold or delay.
    """
    rng = np.random.default_rng(seed)
    parts = [_multisine(n, rng) for _ in range(realizations)]
    u = np.concatenate(parts)
    f = np.fft.rfftfreq(u.size, 1 / FS)
    h = 1 / (K - M * (2 * np.pi * f) ** 2 + 2j * np.pi * f * C)
    scale = X_RMS / np.std(np.fft.irfft(np.fft.rfft(u) * h, u.size))   # linear rms X_RMS
    u *= scale
    fine = np.concatenate([signal.resample(scale * p, 2 * sub * n) for p in parts])
    x = _duffing(fine, sub)
    x_m = x + noise * np.std(x) * rng.standard_normal(x.size)
    u_m = u + noise * np.std(u) * rng.standard_normal(u.size)
    return {'time_s': np.round(np.arange(u.size) / FS, 7), 'displacement_m': x_m,
            'force_N': u_m}


def _plain_linear_nrmse(data):
    """Held-out NRMSE of ``m a + c v + k x`` on FFT derivatives of the whole record (no taper)."""
    x, f = data['displacement_m'], data['force_N']
    n = x.size
    w = 2j * np.pi * np.fft.rfftfreq(n, 1 / FS)
    xs = np.fft.rfft(x - np.mean(x))
    cols = [np.fft.irfft(xs * w ** k, n) for k in (2, 1, 0)]
    mat = np.column_stack(cols + [np.ones(n)])
    tr = slice(int(0.02 * n), int(0.6 * n))
    te = slice(int(0.6 * n), int(0.98 * n))
    theta = np.linalg.lstsq(mat[tr], f[tr], rcond=None)[0]
    return sg.nrmse(f[te], (mat @ theta)[te])


def test_broadband_record_in_volts_at_610_hz_names_cubic_stiffness():
    data = restoring.validate(_record())
    res = restoring.run(data, plots=False)
    assert res['smoothing_differentiator']['method'] == 'spectral, smoothing'
    # the workflow's own linear fit is as good as a plain fit on spectral derivatives
    # (with central differences cut at fs / 5 it left 73 % on this record)
    assert res['nrmse_before'] <= 1.1 * _plain_linear_nrmse(data)
    assert res['effect'] == 'cubic_stiffness'
    assert res['parameters']['cubic_stiffness']['k3'] == pytest.approx(K3, rel=0.1)
    mp = res['model_parameters']
    assert mp['m'] == pytest.approx(M, rel=0.05) and mp['k'] == pytest.approx(K, rel=0.05)
    assert res['gap_closed'] > 0.8


def test_differentiator_follows_the_record():
    rng = np.random.default_rng(1)
    n = 4096
    period = _multisine(n, rng, f_max=150.0)
    x = 1e-3 * np.tile(period, 3)
    t = np.arange(x.size) / FS
    data = restoring.validate({'time_s': t, 'displacement_m': x, 'force_N': 5.0 * x})
    cut, p = restoring.whole_periods(data)
    assert p == n and cut['force_N'].size == 3 * n
    st = restoring.smooth_states(cut, periodic=True)
    assert st['method'] == 'spectral, whole periods'
    f = np.fft.rfftfreq(n, 1 / FS)
    a_true = np.tile(np.fft.irfft(np.fft.rfft(1e-3 * period) * (2j * np.pi * f) ** 2, n), 3)
    assert np.max(np.abs(st['a'] - a_true)) < 1e-6 * np.max(np.abs(a_true))
    # the same band without repetition: the stated smoothing differentiator, exact inside
    # the record (its ends are left out of every fit)
    data = restoring.validate({'time_s': t[:2 * n - 100], 'displacement_m': x[:2 * n - 100],
                               'force_N': 5.0 * x[:2 * n - 100]})
    assert restoring.whole_periods(data)[1] is None
    st = restoring.smooth_states(data)
    assert st['method'] == 'spectral, smoothing'
    mid = slice(n // 4, 2 * n - 100 - n // 4)
    assert np.max(np.abs(st['a'][mid] - a_true[mid])) < 0.02 * np.max(np.abs(a_true))
    # a slow sine at 1 kHz keeps the Butterworth and central differences
    t = np.arange(5000) / 1000.0
    slow = restoring.validate({'time_s': t, 'force_N': np.sin(2 * np.pi * 1.3 * t),
                               'displacement_m': 0.01 * np.sin(2 * np.pi * 1.3 * t + 0.2)})
    assert restoring.smooth_states(slow)['method'] == 'butterworth, central differences'
