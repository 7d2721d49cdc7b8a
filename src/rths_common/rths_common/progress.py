"""Progress of long commands: steps done, rate and ETA on a terminal, quiet in CI logs.

On a terminal (the stream is a TTY) :class:`Progress` redraws one line in place
(carriage return) at most every ``min_interval_s``, and ends it with a newline.
When the stream is not a TTY (CI logs, pipes, files) it writes nothing, so logs
carry no carriage-return spam.  ``RTHS_PROGRESS=1`` forces the line on,
``RTHS_PROGRESS=0`` off.
"""

import os
import sys
import time


def enabled(stream) -> bool:
    """Return True if progress should be drawn on ``stream`` (a TTY, or RTHS_PROGRESS=1)."""
    forced = os.environ.get('RTHS_PROGRESS', '')
    if forced in ('0', '1'):
        return forced == '1'
    isatty = getattr(stream, 'isatty', None)
    return bool(isatty and isatty())


def format_eta(seconds: float | None) -> str:
    """Return ``m:ss`` (or ``h:mm:ss``) of a non-negative duration, ``--:--`` if unknown."""
    if seconds is None or not seconds >= 0 or seconds == float('inf'):
        return '--:--'
    minutes, secs = divmod(int(round(seconds)), 60)
    hours, minutes = divmod(minutes, 60)
    return f'{hours}:{minutes:02d}:{secs:02d}' if hours else f'{minutes}:{secs:02d}'


def line(label: str, done: int, total: int, elapsed_s: float, unit: str = '') -> str:
    """Return the progress text: ``label: done/total unit (pct %), rate/s, ETA m:ss``."""
    unit = f' {unit}' if unit else ''
    rate = done / elapsed_s if elapsed_s > 0 else 0.0
    if total:
        eta = (total - done) / rate if rate > 0 else None
        return (f'{label}: {done}/{total}{unit} ({100.0 * done / total:3.0f} %), '
                f'{rate:.4g}/s, ETA {format_eta(eta)}')
    return f'{label}: {done}{unit}, {rate:.4g}/s'


class Progress:
    """One redrawn progress line for ``total`` steps (0: unknown total)."""

    def __init__(self, total: int, label: str, unit: str = '', stream=None,
                 min_interval_s: float = 0.2, clock=time.monotonic):
        self.total, self.label, self.unit = int(total or 0), label, unit
        self.stream = stream if stream is not None else sys.stderr
        self.on = enabled(self.stream)
        self.min_interval_s = min_interval_s
        self.clock = clock
        self.t0 = clock()
        self._last_draw = None
        self._width = 0
        self.done = 0

    def update(self, done: int, total: int | None = None):
        """Set the steps done (and the total, if given); redraw if the interval has passed."""
        self.done = int(done)
        if total is not None:
            self.total = int(total)
        if not self.on:
            return
        now = self.clock()
        if self._last_draw is not None and now - self._last_draw < self.min_interval_s:
            return
        self._last_draw = now
        text = line(self.label, self.done, self.total, now - self.t0, self.unit)
        pad = max(self._width - len(text), 0)
        self._width = len(text)
        self.stream.write('\r' + text + ' ' * pad)
        self.stream.flush()

    def report(self, done: int, total: int):
        """Take a ``progress(done, total)`` call (the form the cores' callbacks have)."""
        self.update(done, total)

    def advance(self, n: int = 1):
        """Add ``n`` steps done."""
        self.update(self.done + n)

    def close(self):
        """Draw the final state and end the line; nothing when nothing was drawn."""
        if not self.on or self._last_draw is None:
            return
        self._last_draw = None                    # force the last redraw
        self.update(self.done)
        self.stream.write('\n')
        self.stream.flush()
        self._last_draw = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
