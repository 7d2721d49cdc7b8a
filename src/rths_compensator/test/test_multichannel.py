"""Simultaneous multi-channel identification (rths_compensator.multichannel).

The test plant is a coupled 2 x 2 discrete plant in the form of the maRTHS control plant
(rths_common/data/marths.json): each input has its own denominator (its own poles, shared by
both outputs), one slow pole, a one-sample delay, and ~15 % coupling off the diagonal.  A
shared-denominator multi-input ARX cannot represent it without bias; the state-space fit
must recover its transfer matrix from one test with both inputs excited at once.
"""

import math

import numpy as np
import pytest
from scipy import signal

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
