"""Online stability monitor: how well the actuator tracks its target, while the test runs.

``StabilityMonitor(fs_hz, settings).step(target, measured)`` takes the target (interface)
displacement and the measured displacement of one step and returns its
:class:`MonitorState`.  Estimates, over exponential windows of ``window_s``:

``delay_ms``, ``gain``
    the tracking delay and amplitude: the running least-squares fit of the measured
    displacement by ``gain x - gain delay xd`` of the target x and its rate xd (the first
    two terms of ``gain x(t - delay)``; the inverse relation the adaptive time-series
    compensator fits, Chae et al. 2013), O(1) per step.
``error_pct``
    the relative RMS tracking error ``rms(measured - target) / rms(target)``.
``ti``
    the tracking indicator of Mercan & Ricles (2007): the area enclosed by the
    target-measured curve (the trapezoid sum ``0.5 (x_k + x_{k-1})(y_k - y_{k-1}) - 0.5
    (y_k + y_{k-1})(x_k - x_{k-1})``), exponentially forgotten and normalised by the
    target's mean square; it grows positive when the actuator lags, negative when it leads.

Decisions (``level``: 0 ok, 1 warn, 2 stop) are taken only while the target is excited
(RMS >= ``excitation_m``) and after ``settle_s``: warn when the delay or the error passes
its warn threshold, stop when either passes its stop threshold for ``hold_s`` in a row.
A stop is latched.  The thresholds are :class:`MonitorSettings` (documented defaults:
docs/monitor.md).
"""

import dataclasses
import math

import numpy as np

OK, WARN, STOP = 0, 1, 2
LEVELS = ('ok', 'warn', 'stop')


@dataclasses.dataclass
class MonitorSettings:
    """Thresholds and windows of the monitor (SI units; delays in ms, errors in %)."""

    warn_delay_ms: float = 3.0
    stop_delay_ms: float = 5.0
    warn_error_pct: float = 25.0
    stop_error_pct: float = 50.0
    window_s: float = 0.25
    excitation_m: float = 2.54e-4
    settle_s: float = 1.0
    hold_s: float = 0.05

    def check(self):
        """Raise ValueError naming the setting that is not usable."""
        for name in ('warn_delay_ms', 'stop_delay_ms', 'warn_error_pct', 'stop_error_pct',
                     'window_s', 'excitation_m'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f'monitor setting {name} = {value}: give a positive number')
        if self.stop_delay_ms < self.warn_delay_ms or self.stop_error_pct < self.warn_error_pct:
            raise ValueError('monitor settings: a stop threshold below its warn threshold')


def settings_from_params(params: dict) -> MonitorSettings:
    """Return the settings of compensator parameters (``monitor_*``; defaults otherwise)."""
    base = MonitorSettings()
    names = ('warn_delay_ms', 'stop_delay_ms', 'warn_error_pct', 'stop_error_pct')
    return dataclasses.replace(base, **{n: float(params.get(f'monitor_{n}', getattr(base, n)))
                                        for n in names})


@dataclasses.dataclass
class MonitorState:
    """The estimates and the decision after one step."""

    delay_ms: float = 0.0
    gain: float = 1.0
    error_pct: float = 0.0
    ti: float = 0.0
    level: int = OK
    reason: str = ''


class StabilityMonitor:
    """The running estimates and the warn/stop decision of one channel (see module doc)."""

    def __init__(self, fs_hz: float, settings: MonitorSettings = None):
        self.settings = s = settings or MonitorSettings()
        s.check()
        self.fs_hz = float(fs_hz)
        self.alpha = 1.0 / max(1.0, s.window_s * self.fs_hz)
        self.sums = np.zeros(5)     # running means of x x, x v, v v, x y, v y (v = rate)
        self.ms_x = 0.0
        self.ms_e = 0.0
        self.area = 0.0
        self.prev = None
        self.k = 0
        self.settle = int(round(s.settle_s * self.fs_hz))
        self.hold = max(1, int(round(s.hold_s * self.fs_hz)))
        self.over = 0
        self.state = MonitorState()

    def step(self, target: float, measured: float) -> MonitorState:
        """Update with one step; return the state (a stop is latched)."""
        st = self.state
        if st.level == STOP:
            return st
        x, y = float(target), float(measured)
        if not (math.isfinite(x) and math.isfinite(y)):
            return self._stop(f'non-finite target or measurement ({x}, {y})')
        a = self.alpha
        e = y - x
        self.ms_x += a * (x * x - self.ms_x)
        self.ms_e += a * (e * e - self.ms_e)
        if self.prev is not None:
            px, py = self.prev
            self.area += 0.5 * ((x + px) * (y - py) - (y + py) * (x - px)) - a * self.area
            self._fit(x, (x - px) * self.fs_hz, y)
        self.prev = (x, y)
        self.k += 1
        st.error_pct = 100.0 * math.sqrt(self.ms_e / self.ms_x) if self.ms_x > 0 else 0.0
        st.ti = self.area / self.ms_x if self.ms_x > 0 else 0.0
        return self._decide(st)

    def _fit(self, x, v, y):
        sums = self.sums
        a = self.alpha
        sums[0] += a * (x * x - sums[0])
        sums[1] += a * (x * v - sums[1])
        sums[2] += a * (v * v - sums[2])
        sums[3] += a * (x * y - sums[3])
        sums[4] += a * (v * y - sums[4])
        sxx, sxv, svv, sxy, svy = sums
        det = sxx * svv - sxv * sxv
        if det > 1e-12 * sxx * svv and sxx > 0.0:
            gain = (sxy * svv - svy * sxv) / det
            slope = (svy * sxx - sxy * sxv) / det
            if gain > 0.0:
                self.state.gain = gain
                self.state.delay_ms = -1e3 * slope / gain

    def _decide(self, st):
        s = self.settings
        if self.k < self.settle or self.ms_x < s.excitation_m ** 2:
            st.level, st.reason = OK, ''
            self.over = 0
            return st
        delay = abs(st.delay_ms)
        if delay >= s.stop_delay_ms or st.error_pct >= s.stop_error_pct:
            self.over += 1
            if self.over >= self.hold:
                return self._stop(f'tracking delay {st.delay_ms:.1f} ms (stop at '
                                  f'{s.stop_delay_ms:g}), error {st.error_pct:.1f} % (stop at '
                                  f'{s.stop_error_pct:g})')
        else:
            self.over = 0
        if delay >= s.warn_delay_ms or st.error_pct >= s.warn_error_pct:
            st.level = WARN
            st.reason = (f'tracking delay {st.delay_ms:.1f} ms, error {st.error_pct:.1f} %')
        else:
            st.level, st.reason = OK, ''
        return st

    def _stop(self, reason):
        self.state.level = STOP
        self.state.reason = reason
        return self.state
