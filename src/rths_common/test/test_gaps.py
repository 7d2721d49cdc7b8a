"""Interpolation over lost steps (rths_common.gaps): exactness, error bounds, the policy."""

import numpy as np
import pytest

from rths_common import gaps

FS_HZ = 1024.0
DT = 1.0 / FS_HZ


def sines(steps):
    """Return a 1-3 Hz sum of sines [m] (peak ~10 mm) at the steps, and bounds of its derivatives.

    ``bound[r]`` = sum of amplitude * (2 pi f)^r >= max|x^(r)| (triangle inequality).
    """
    amp = np.array([0.006, 0.003, 0.0015])
    freq = np.array([1.0, 2.0, 3.0])
    phase = np.array([0.0, 0.7, 1.3])
    t = np.asarray(steps, dtype=float)[:, None] * DT
    x = np.sin(2 * np.pi * freq * t + phase) @ amp
    bound = {r: float(np.sum(amp * (2 * np.pi * freq) ** r)) for r in range(5)}
    return x, bound


def test_linear_fill_is_exact_on_a_ramp_per_channel():
    filler = gaps.GapFiller(order=1)

    def ramp(k):  # two DOFs
        return np.array([0.5 + 2e-3 * k, -1.0 - 7e-4 * k])

    assert filler.fill(10, ramp(10)).shape == (0, 2)     # nothing before: nothing to fill
    assert filler.fill(11, ramp(11)).shape == (0, 2)     # consecutive: nothing lost
    filled = filler.fill(15, ramp(15))                   # 12, 13, 14 lost
    np.testing.assert_allclose(filled, [ramp(k) for k in (12, 13, 14)], rtol=0, atol=1e-15)


def test_cubic_fill_is_exact_on_a_cubic():
    def cubic(k):
        return 1e-3 * (2.0 + 0.3 * k - 0.05 * k ** 2 + 0.004 * k ** 3)

    filler = gaps.GapFiller(order=3)
    for k in (0, 1, 2, 3):
        assert filler.fill(k, cubic(k)).size == 0
    filled = filler.fill(6, cubic(6))                     # 4 and 5 lost: nodes 1, 2, 3, 6
    np.testing.assert_allclose(filled[:, 0], [cubic(4), cubic(5)], rtol=1e-12)


@pytest.mark.parametrize('order, lost', [(1, 1), (1, 4), (3, 1), (3, 2), (3, 3)])
def test_error_within_the_lagrange_bound_and_far_below_hold(order, lost):
    """On the 1-3 Hz signal, at many gap positions: |error| <= error_bound, << hold's."""
    worst_ratio, gains = 0.0, []
    for a in range(200, 10000, 97):
        b = a + lost + 1
        known = np.arange(a - order + 1, a + 1)
        x_known, bound = sines(known)
        x_b, _ = sines([b])
        filler = gaps.GapFiller(order=order)
        for k, v in zip(known, x_known, strict=True):
            filler.fill(int(k), v)
        missing = np.arange(a + 1, b)
        filled = filler.fill(b, x_b[0])[:, 0]
        err = np.abs(filled - sines(missing)[0])
        nodes = list(known) + [b]
        limit = gaps.error_bound(nodes, missing, bound[order + 1], DT)
        assert np.all(err <= limit * (1 + 1e-9) + 1e-15), (a, err, limit)
        worst_ratio = max(worst_ratio, float(np.max(err / limit)))
        hold = np.abs(sines(missing)[0] - x_known[-1])
        assert np.all(hold <= gaps.hold_error_bound(a, missing, bound[1], DT) + 1e-15)
        gains.append(float(np.max(hold) / max(np.max(err), 1e-300)))
    assert worst_ratio > 0.1          # the bound is not vacuous: some gap comes close to it
    # typical gain over hold (median over the positions; near a turning point x' ~ 0 and
    # hold is good too).  Measured: linear 153 (1 lost) / 104 (4 lost), cubic 2.6e5-8.6e5
    assert np.median(gains) > {1: 50.0, 3: 1e4}[order]


def test_documented_single_step_bounds():
    """One lost step: linear max|x''| dt^2 / 2; cubic (a-2, a-1, a, b) max|x''''| dt^4 / 4."""
    np.testing.assert_allclose(gaps.error_bound([0, 2], [1], 1.0, DT), [DT ** 2 / 2])
    np.testing.assert_allclose(gaps.error_bound([-2, -1, 0, 2], [1], 1.0, DT), [DT ** 4 / 4])
    # linear over a gap of n steps: at most n^2 dt^2 / 8 (mid-gap)
    n = 6
    assert np.max(gaps.error_bound([0, n], np.arange(1, n), 1.0, DT)) == pytest.approx(
        n ** 2 * DT ** 2 / 8)


def test_back_to_back_gaps_keep_a_cubic_through_received_steps():
    """Lost 200 and 202: the second gap uses 198, 199, 201 (received) and 203, exactly."""
    def cubic(k):
        return 1e-3 * (1.0 + 0.02 * k - 3e-4 * k ** 2 + 2e-6 * k ** 3)

    filler = gaps.GapFiller(order=3)
    for k in (196, 197, 198, 199):
        filler.fill(k, cubic(k))
    assert filler.fill(201, cubic(201))[0, 0] == pytest.approx(cubic(200), rel=1e-12)
    assert filler.last_nodes == [197, 198, 199, 201]
    assert filler.fill(203, cubic(203))[0, 0] == pytest.approx(cubic(202), rel=1e-12)
    assert filler.last_nodes == [198, 199, 201, 203]


@pytest.mark.parametrize('lost, nodes', [(3, [2, 3, 4]), (4, [3, 4]), (13, [3, 4]), (15, [4])])
def test_longer_gaps_lower_the_order(lost, nodes):
    """The highest order whose Lebesgue constant over the gap is <= MAX_LEBESGUE (8).

    Cubic up to 3 lost steps (7.4; 4 lost: 11.0), then quadratic (4 lost: 3.0,
    13 lost: 7.5), then linear (15 lost: quadratic 8.5).
    """
    rng = np.random.default_rng(lost)
    filler = gaps.GapFiller(order=3)
    known = rng.normal(size=(5, 2))
    for k in range(5):
        filler.fill(k, known[k])
    b = 4 + lost + 1
    new = rng.normal(size=2)
    filled = filler.fill(b, new)
    assert filler.last_nodes == nodes + [b]
    missing = np.arange(5, b)
    values = np.vstack([known[nodes], new])
    np.testing.assert_allclose(filled, gaps.interpolate(nodes + [b], values, missing),
                               rtol=1e-12, atol=1e-12)
    lebesgue = np.abs(gaps.lagrange_weights(nodes + [b], missing)).sum(axis=1).max()
    assert lebesgue <= gaps.MAX_LEBESGUE
    if len(nodes) < 3:   # one more node would have broken the limit
        wider = [nodes[0] - 1] + nodes + [b]
        assert np.abs(gaps.lagrange_weights(wider, missing)).sum(axis=1).max() > \
            gaps.MAX_LEBESGUE
    if len(nodes) == 1:  # linear: the straight line between the two ends
        np.testing.assert_allclose(
            filled, known[4] + np.outer((missing - 4) / (b - 4), new - known[4]), rtol=1e-12)


def test_warm_up_caches_the_weights_of_short_gaps():
    """The nodes' start-up call leaves the contiguous 1-3 lost-step patterns cached."""
    gaps._gap_weights.cache_clear()
    gaps.warm_up(3)
    assert gaps._gap_weights.cache_info().currsize == 3
    filler = gaps.GapFiller(3)
    for k in range(3):
        filler.fill(k, [0.0])
    filler.fill(5, [1.0])   # 2 lost: a hit
    assert gaps._gap_weights.cache_info().hits >= 1
    assert gaps._gap_weights.cache_info().currsize == 3


def test_stale_or_repeated_step_is_refused():
    filler = gaps.GapFiller(order=3)
    filler.fill(5, [1.0])
    with pytest.raises(ValueError, match='not after the last received step 5'):
        filler.fill(5, [1.0])
    with pytest.raises(ValueError, match='order must be >= 1'):
        gaps.GapFiller(order=0)


def test_node_policies():
    """The orders the nodes use (module docstring): cubic displacements, linear forces."""
    assert gaps.DISPLACEMENT_ORDER == 3
    assert gaps.FORCE_ORDER == 1
