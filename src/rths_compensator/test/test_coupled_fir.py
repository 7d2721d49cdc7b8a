"""The coupled N x N FIR of a multi-actuator rig (``coupled_taps``, filters.CoupledFir)."""

import numpy as np
import pytest

from rths_compensator.core import CompensatorCore
from rths_compensator.filters import CoupledFir
from rths_compensator.params import coupled_taps_of


def _direct(taps, x):
    """``y_i(k) = sum_l sum_j taps[i, l, j] x_l(k - j)`` by loops."""
    n_ch, _, n = taps.shape
    y = np.zeros_like(x)
    for k in range(x.shape[0]):
        for i in range(n_ch):
            y[k, i] = sum(taps[i, m, j] * x[k - j, m] for m in range(n_ch) for j in range(n)
                          if k - j >= 0)
    return y


def test_each_command_answers_every_target_as_the_convolution():
    rng = np.random.default_rng(2)
    taps = rng.standard_normal((2, 2, 7))
    x = rng.standard_normal((40, 2))
    f = CoupledFir(taps)
    y = np.array([f.step(row) for row in x])
    assert np.max(np.abs(y - _direct(taps, x))) < 1e-12
    f.reset()
    assert np.allclose(f.step(x[0]), taps[:, :, 0] @ x[0])


def test_the_compensator_core_runs_the_coupled_taps_in_their_flat_order():
    rng = np.random.default_rng(4)
    taps = rng.standard_normal((2, 2, 5))
    params = {'taps': [1.0], 'denominator': [1.0], 'fs_hz': 1024.0, 'scheme': 'ls',
              'coupled_taps': taps.ravel().tolist()}
    core = CompensatorCore(params)
    x = rng.standard_normal((12, 2))
    y = np.array([core.step(k, row).output for k, row in enumerate(x)])
    assert np.max(np.abs(y - _direct(taps, x))) < 1e-12
    # one value (the parameter's default): the designed filter per channel, unchanged
    plain = CompensatorCore(dict(params, coupled_taps=[0.0], taps=[2.0]))
    assert np.allclose(plain.step(0, np.array([1.0, -1.0])).output, [2.0, -2.0])


def test_taps_that_are_not_n_by_n_or_not_finite_or_with_an_adaptive_method_are_refused():
    core = CompensatorCore({'taps': [1.0], 'denominator': [1.0], 'fs_hz': 1024.0,
                            'scheme': 'ls', 'coupled_taps': [0.1] * 6})
    with pytest.raises(ValueError, match='not N x N x n taps for N = 2'):
        core.step(0, np.zeros(2))
    with pytest.raises(ValueError, match='nan/inf'):
        coupled_taps_of({'coupled_taps': [0.1, float('nan')]})
    with pytest.raises(ValueError, match='set method: fir'):
        coupled_taps_of({'coupled_taps': [0.1] * 8, 'method': 'ats'})
    assert coupled_taps_of({'coupled_taps': [0.0]}) is None
