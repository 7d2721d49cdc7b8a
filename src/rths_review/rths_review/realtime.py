"""Was a realtime run real time? Its figures from the bridge's ticks, against the user's limits.

The bridge is the clock of a realtime run: tick k is due at ``t0 + k / fs``
(:class:`rths_common.stepping.TickClock`) and each tick publishes a status
stamped when it ran. From those stamps (:func:`realtime_figures`):

* ``clock_overruns``: ticks that ran more than a period late; the clock then
  re-anchors (as ``TickClock`` does), and the ticks the stall skipped are
  ``stalled_ticks``;
* ``late_or_missed_pct``: deadline misses (``missed_ticks``: ticks whose command
  had not arrived) plus stalled ticks, over all ticks due (``rths bench loop``'s
  figure);
* ``worst_period_ms``: the longest time between two ticks;
* ``behind_s``: how much longer than real time the ticks took
  (wall time from the first to the last tick minus the steps' time);
* ``realtime_ok``: every figure within :data:`REALTIME_LIMITS` (or the limits
  the user gave ``rths run`` / ``rths review``).
"""

import numpy as np

#: Default limits of a real-time run [unit in the key]: the share of ticks late or missed
#: (``rths bench loop``'s target), the longest tick period, the total time behind.
REALTIME_LIMITS = {'late_or_missed_pct': 0.1, 'worst_period_ms': 10.0, 'behind_s': 0.1}


def check_limits(limits: dict) -> dict:
    """Return ``limits`` merged over :data:`REALTIME_LIMITS`; ValueError for a bad one."""
    out = dict(REALTIME_LIMITS)
    for key, value in (limits or {}).items():
        if key not in REALTIME_LIMITS:
            raise ValueError(f'unknown real-time limit {key!r}; use '
                             f'{", ".join(REALTIME_LIMITS)}')
        if value is None:
            continue
        if not (isinstance(value, (int, float)) and np.isfinite(value) and value >= 0):
            raise ValueError(f'real-time limit {key} = {value!r} must be a number >= 0')
        out[key] = float(value)
    return out


def realtime_figures(stamp_ns, missed, fs_hz: float, limits: dict = None) -> dict:
    """Return the figures above from the bridge's ticks of a run, in step order (pure).

    ``stamp_ns``: wall time each tick ran [ns]; ``missed``: whether its command
    was missing (a deadline miss).
    """
    limits = check_limits(limits)
    t = np.asarray(stamp_ns, dtype=np.int64)
    missed = np.asarray(missed, dtype=bool)
    period_ns = int(round(1e9 / float(fs_hz)))
    overruns = stalled = 0
    anchor, k_anchor = (int(t[0]), 0) if t.size else (0, 0)
    for k, now in enumerate(t.tolist()):
        late = now - (anchor + (k - k_anchor) * period_ns)
        if late > period_ns:
            overruns += 1
            stalled += late // period_ns
            anchor, k_anchor = now, k
    due = int(t.size) + stalled
    misses = int(missed.sum())
    periods = np.diff(t)
    out = {
        'ticks': int(t.size),
        'missed_ticks': misses,
        'clock_overruns': overruns,
        'stalled_ticks': int(stalled),
        'late_or_missed_pct': round(100.0 * (misses + stalled) / due, 4) if due else 0.0,
        'worst_period_ms': round(float(periods.max()) * 1e-6, 3) if periods.size else 0.0,
        'behind_s': round(max(0.0, float(t[-1] - t[0]) * 1e-9 - (t.size - 1) / float(fs_hz)),
                          4) if t.size else 0.0,
        'realtime_limits': limits,
    }
    out['realtime_ok'] = all(out[key] <= limit for key, limit in limits.items())
    return out


def realtime_text(s: dict) -> str:
    """Return one line of the review: the figures and the verdict against the limits."""
    lim = s['realtime_limits']
    verdict = ('real time' if s['realtime_ok'] else
               'NOT REAL TIME: beyond ' + ', '.join(
                   f'{key} {lim[key]:g}' for key in REALTIME_LIMITS if s[key] > lim[key]))
    return (f"real time: {s['late_or_missed_pct']:.3f} % of ticks late or missed "
            f"({s['missed_ticks']} without their command, {s['clock_overruns']} clock overruns "
            f"skipping {s['stalled_ticks']} ticks), worst period {s['worst_period_ms']:.3f} ms, "
            f"{s['behind_s']:.3f} s behind: {verdict}")
