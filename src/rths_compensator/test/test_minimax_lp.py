"""The minimax (MM) FIR design's LP (eq. 33): conditioning of the cutting planes, fallbacks."""

import numpy as np
import pytest

from rths_compensator import design as dsg
from rths_compensator.bench import BENCH_ZERO_TOL
from rths_compensator.identification import ArxModel
from rths_compensator.plants import discrete_actuator

FS = 1024.0

#: The ARX plant (BIC, na = 12, nb = 8) that ``rths bench compensators`` identifies with its
#: default seed 2024 (zero moduli 2.83, 1.62 x 2, 0.9956 x 2, 0.73 x 2): with it the MM
#: design n = 300, fc = 128 Hz failed ("mm design LP failed (HiGHS status 4)").
BENCH_PLANT_A = [
    1.0, -0.566365996745807, -0.4149763906475072, -0.2684751899757467, -0.13604916340641776,
    -0.021865455948871453, 0.07409657336161769, 0.1401771436918152, 0.16899370065480931,
    0.16732166135350535, 0.10430146558505546, -0.020164463251844865, -0.2056720462962855]
BENCH_PLANT_B = [
    -0.014513574305189288, 0.1012704908848024, -0.3081003390094903, 0.5681841907916549,
    -0.6556814342545926, 0.5013850367450443, -0.2278992097060559, 0.05667103410883858]


@pytest.fixture(scope='module')
def plant():
    """Return the 3-pole model with an extra unstable zero at 1.664 (as in the seed's eq. 41)."""
    b, a = discrete_actuator('3pole', FS)
    b = np.convolve(b, [-1 / 1.664, 1.0]) / (1 - 1 / 1.664)
    return ArxModel(a=a, b=b, d=0, fs_hz=FS)


def _record_relaxations(monkeypatch):
    """Record ``(t, max |g|)`` of every cutting-plane relaxation solved."""
    seen = []
    solve = dsg._IncrementalLp.solve

    def recording(self):
        x, status = solve(self)
        if x is not None:
            seen.append((float(x[-1]), float(np.max(np.abs(x[:-1])))))
        return x, status

    monkeypatch.setattr(dsg._IncrementalLp, 'solve', recording)
    return seen


def test_bench_mm_n300_fc128_is_designed_within_its_constraints():
    """Regression: the bench's fir-mm-n300-fc128 (identified plant, zero_tol 0.98)."""
    plant = ArxModel(a=BENCH_PLANT_A, b=BENCH_PLANT_B, d=0, fs_hz=FS)
    comp = dsg.design_fir(plant, 300, 128.0, 'mm', dsg.DEFAULT_EPSILON,
                          zero_tol=BENCH_ZERO_TOL)
    assert comp.info['passband_max_error'] <= dsg.DEFAULT_EPSILON
    assert comp.info['dc_gain_error'] < 1e-8
    assert np.max(np.abs(np.roots(comp.denominator))) < BENCH_ZERO_TOL


def test_first_relaxation_bounds_the_taps(plant, monkeypatch):
    """A sparse first objective grid lets the LP interpolate on a wild vertex.

    With n = 60 taps and a 65-point grid, every 8th point gives 9 points (18 equations):

    that relaxation interpolates (t = 0) on an arbitrary vertex with |g| hundreds of times
    the final |g| -- the ill-conditioning that made HiGHS fail on larger designs.  The
    first relaxation must hold enough points for t > 0 and a bounded g.
    """
    seen = _record_relaxations(monkeypatch)
    comp = dsg.design_fir(plant, 60, 64.0, 'mm', 0.005, n_grid=65)
    assert len(seen) >= 1 and comp.info['passband_max_error'] <= 0.005
    t_first, g_final = seen[0][0], seen[-1][1]
    assert t_first > 0.1 * seen[-1][0]
    assert max(g for _, g in seen) <= 10 * g_final


def test_distinct_sides_drop_redundant_rows():
    """0 Hz rows are implied by sum(g) = 1; at Nyquist only the sides cos = +-1 remain."""
    b_minus = np.array([-0.6, 1.0])
    b_minus = b_minus / np.sum(b_minus)
    freqs = np.array([0.0, 100.0, FS / 2])
    m = dsg._fir_matrix(b_minus, 0, 12, freqs, FS)
    rot = dsg._polygon(8)
    valid = dsg._distinct_sides(m, rot)
    assert not valid[:, 0].any()
    assert valid[:, 1].all()
    assert sorted(np.round(np.real(rot[valid[:, 2]]), 12)) == [-1.0, 1.0]
    # the kept Nyquist rows imply the dropped ones: |x| = max(x, -x) >= cos(theta) x
    rows = np.real(rot[:, None] * m[2][None, :])
    g = np.random.default_rng(1).standard_normal(12)
    assert np.max(rows[valid[:, 2]] @ g) >= np.max(rows @ g) - 1e-12


def test_incremental_lp_scales_rows_and_handles_empty_rows():
    """Rows are stored at unit norm; empty rows are dropped or make the LP infeasible.

    Rows are stored at unit norm; an empty row that holds is dropped, one that cannot
    hold (0 <= negative) makes the LP infeasible.
    """
    lp = dsg._IncrementalLp([0.0, 1.0], [[1.0, 0.0]], [2.0])
    lp.add_rows([[300.0, -300.0], [0.0, 0.0], [-0.01, -0.01]], [0.0, 1.0, 0.0])
    assert lp.rows[0].shape == (2, 2)
    np.testing.assert_allclose(np.linalg.norm(lp.rows[0], axis=1), 1.0)
    x, status = lp.solve()                       # min t s.t. x0 = 2, t >= x0, t >= -x0
    assert status == 0
    np.testing.assert_allclose(x, [2.0, 2.0], atol=1e-9)
    lp.add_rows([[0.0, 0.0]], [-1.0])
    assert lp.solve() == (None, 2)


class _FailingHighs:
    """A HiGHS instance whose warm-started run ends in a solve error (status 4)."""

    def __init__(self, highs, status):
        self._highs, self._status = highs, status

    def __getattr__(self, name):
        return getattr(self._highs, name)

    def run(self):
        return None

    def getModelStatus(self):
        return self._status


def test_solve_error_falls_back_to_cold_solves(monkeypatch):
    lp = dsg._IncrementalLp([0.0, 1.0], [[1.0, 0.0]], [2.0])
    if lp.highs is None:
        pytest.skip('SciPy without the HiGHS core: every solve is already a cold linprog')
    lp.add_rows([[1.0, -1.0], [-1.0, -1.0]], [0.0, 0.0])
    lp.highs = _FailingHighs(lp.highs, lp._core.HighsModelStatus.kSolveError)
    tried = []
    linprog_free = dsg._linprog_free

    def failing_highs(c, a_ub, b_ub, a_eq, b_eq, method='highs'):
        tried.append(method)
        if method == 'highs':
            return None, 4
        return linprog_free(c, a_ub, b_ub, a_eq, b_eq, method)

    monkeypatch.setattr(dsg, '_linprog_free', failing_highs)
    x, status = lp.solve()
    assert tried == ['highs', 'highs-ds']
    assert status == 0
    np.testing.assert_allclose(x, [2.0, 2.0], atol=1e-9)
