"""The step contract's pieces: the gap policy, the driver, the tick clock (rths_common.stepping)."""

import numpy as np
import pytest

from rths_common import gaps
from rths_common.stepping import Driver, GapPolicy, StaleStep, StepResult, TickClock


class Summer:
    """A core that adds up its inputs (one per step, filled ones included)."""

    def __init__(self, order=1):
        self.policy = GapPolicy(order)
        self.seen = []

    @property
    def next_step(self):
        return self.policy.next_step

    def step(self, k, u):
        x, rows = self.policy.admit(k, u)
        self.seen += [float(r[0]) for r in rows] + [float(x[0])]
        self.policy.passed(k)
        return StepResult(k, (np.array([sum(self.seen)]),), len(rows))


def test_gap_policy_interpolates_lost_steps_and_refuses_stale_ones():
    core = Summer(order=1)
    for k in (0, 1):
        core.step(k, [float(k)])
    result = core.step(4, [4.0])           # 2 and 3 lost: linear through 1 and 4
    assert result.filled == 2
    assert core.seen == [0.0, 1.0, 2.0, 3.0, 4.0]
    assert core.next_step == 5
    with pytest.raises(StaleStep, match='step 3 is stale'):
        core.step(3, [0.0])


def test_gap_policy_fills_with_the_first_value_when_nothing_came_before():
    core = Summer()
    assert core.step(3, [7.0]).filled == 3
    assert core.seen == [7.0] * 4


def test_gap_policy_uses_the_cubic_of_rths_common_gaps():
    policy = GapPolicy(gaps.DISPLACEMENT_ORDER)
    t = np.arange(8) / 1024.0
    x = np.sin(2 * np.pi * 3.0 * t)
    for k in range(4):
        policy.admit(k, [x[k]])
        policy.passed(k)
    _, rows = policy.admit(5, [x[5]])
    expected = gaps.interpolate([1, 2, 3, 5], x[[1, 2, 3, 5]], [4])
    assert np.array_equal(np.asarray(rows), expected)


@pytest.mark.parametrize('lockstep, accepted', [(True, [0, 1, 2]), (False, [0, 1, 3])])
def test_driver_lockstep_takes_only_the_expected_step_realtime_the_newest(lockstep, accepted):
    rejects = []
    driver = Driver(Summer(), lockstep, on_reject=lambda k, e: rejects.append((k, e)))
    taken = [k for k in (0, 1, 1, 3, 2) if driver.feed(k, [1.0]) is not None]
    if lockstep:   # 1 twice (duplicate), 3 (ahead): rejected; 2 then taken
        assert taken == [0, 1, 2] and rejects == [(1, 2), (3, 2)]
    else:          # 1 twice and 2 after 3: stale
        assert taken == accepted and rejects == [(1, 2), (2, 4)]
    assert driver.rejected == 2


def test_tick_clock_hands_out_steps_and_reanchors_after_a_stall():
    clock = TickClock(1000.0)
    assert not clock.running
    clock.start(1_000_000)
    assert clock.take(1_000_000 + 50_000) == (0, 50_000, 0)
    assert clock.due_ns() == 2_000_000
    k, late, skipped = clock.take(2_000_000 + 3_500_000)   # 3.5 periods late: a stall
    assert (k, late, skipped) == (1, 3_500_000, 3)
    assert clock.overruns == 1
    assert clock.due_ns() == 5_500_000 + 1_000_000           # a period after the late tick


def test_step_result_defaults():
    result = StepResult(4)
    assert result.output is None and result.filled == 0 and not result.done
    assert dict(result.channels) == {}
