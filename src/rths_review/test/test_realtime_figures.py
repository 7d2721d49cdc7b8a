"""The real-time figures of a run's ticks agree with the bridge's own clock (TickClock)."""

import numpy as np
import pytest

from rths_common.stepping import TickClock
from rths_review.realtime import check_limits, realtime_figures

FS = 1024.0


def _ticks_through_the_clock(stalls):
    """Wall times of 5000 ticks taken by a TickClock whose thread stalls ``stalls`` (ns)."""
    clock = TickClock(FS)
    clock.start(0)
    now, times = 0, []
    overruns = skipped = 0
    for k in range(5000):
        now = max(now, clock.due_ns()) + stalls.get(k, 0)
        _, _, skip = clock.take(now)
        skipped += skip
        times.append(now)
    overruns = clock.overruns
    return times, overruns, skipped


def test_figures_match_the_clock_that_ran_the_ticks():
    rng = np.random.default_rng(3)
    stalls = {int(k): int(rng.integers(200_000, 40_000_000)) for k in rng.integers(1, 5000, 12)}
    times, overruns, skipped = _ticks_through_the_clock(stalls)
    missed = np.zeros(5000, dtype=bool)
    missed[[10, 11, 400]] = True
    f = realtime_figures(times, missed, FS)
    assert (f['clock_overruns'], f['stalled_ticks']) == (overruns, skipped)
    assert overruns > 0
    assert f['late_or_missed_pct'] == pytest.approx(100 * (3 + skipped) / (5000 + skipped),
                                                    abs=1e-4)
    assert f['worst_period_ms'] == pytest.approx(max(np.diff(times)) * 1e-6, abs=1e-3)
    assert f['behind_s'] == pytest.approx((times[-1] - 4999 * 1e9 / FS) * 1e-9, abs=1e-3)
    assert f['realtime_ok'] is False


def test_limits_are_checked():
    assert check_limits({'behind_s': 1})['behind_s'] == 1.0
    with pytest.raises(ValueError, match="unknown real-time limit 'late_pct'"):
        check_limits({'late_pct': 1})
    with pytest.raises(ValueError, match='worst_period_ms = -1 must be a number >= 0'):
        check_limits({'worst_period_ms': -1})
