"""Progress of long commands: steps done, rate and ETA; one line on a terminal, few in logs.

Every ``rths`` command that can run longer than a few seconds reports its
progress through :class:`Progress`, on stderr (stdout keeps the results, JSON
and tables).  The stream decides the form (:func:`mode`):

* ``tty`` (a terminal): one line redrawn in place (carriage return) at most
  every ``min_interval_s``, ended with a newline when the work is done;
* ``log`` (not a terminal: CI logs, pipes, files): a plain line, no carriage
  return, when another ``log_pct`` percent is done or ``log_s`` seconds have
  passed since the last line, at most one a second and none in the first
  second, and the final state when it ends (a job that ends within a second
  writes nothing);
* ``off``: ``--quiet`` (:func:`apply_quiet`) or ``RTHS_PROGRESS=0``.

``RTHS_PROGRESS=1`` forces ``tty``, ``RTHS_PROGRESS=log`` forces ``log``.
"""

import contextlib
import os
import sys
import threading
import time

#: Values of RTHS_PROGRESS that force a mode.
FORCED = {'0': 'off', '1': 'tty', 'log': 'log', 'tty': 'tty', 'off': 'off'}


def mode(stream) -> str:
    """Return how progress is shown on ``stream``: ``tty``, ``log`` or ``off``."""
    forced = os.environ.get('RTHS_PROGRESS', '').strip().lower()
    if forced in FORCED:
        return FORCED[forced]
    isatty = getattr(stream, 'isatty', None)
    try:
        return 'tty' if isatty and isatty() else 'log'
    except ValueError:                      # a closed stream
        return 'off'


def enabled(stream) -> bool:
    """Return True if ``stream`` gets the redrawn terminal line (a TTY, or RTHS_PROGRESS=1)."""
    return mode(stream) == 'tty'


def add_quiet_argument(parser):
    """Add ``--quiet`` (no progress lines; results are still printed) to a sub-command."""
    parser.add_argument('--quiet', action='store_true',
                        help='no progress lines on stderr (results are still printed)')


def apply_quiet(args):
    """Turn progress off for this process and its children if ``args.quiet`` is set."""
    if getattr(args, 'quiet', False):
        os.environ['RTHS_PROGRESS'] = '0'


def format_eta(seconds: float | None) -> str:
    """Return ``m:ss`` (or ``h:mm:ss``) of a non-negative duration, ``--:--`` if unknown."""
    if seconds is None or not seconds >= 0 or seconds == float('inf'):
        return '--:--'
    minutes, secs = divmod(int(round(seconds)), 60)
    hours, minutes = divmod(minutes, 60)
    return f'{hours}:{minutes:02d}:{secs:02d}' if hours else f'{minutes}:{secs:02d}'


def format_rate(rate: float) -> str:
    """Return ``N/s``, or ``T s each`` when a step takes longer than a second."""
    return f'{1.0 / rate:.3g} s each' if 0 < rate < 1 else f'{rate:.4g}/s'


def line(label: str, done: int, total: int, elapsed_s: float, unit: str = '') -> str:
    """Return the progress text: ``label: done/total unit (pct %), rate/s, ETA m:ss``."""
    unit = f' {unit}' if unit else ''
    rate = done / elapsed_s if elapsed_s > 0 else 0.0
    if total:
        eta = (total - done) / rate if rate > 0 else None
        return (f'{label}: {done}/{total}{unit} ({100.0 * done / total:3.0f} %), '
                f'{format_rate(rate)}, ETA {format_eta(eta)}')
    return f'{label}: {done}{unit}, {format_rate(rate)}, {format_eta(elapsed_s)} elapsed'


class Progress:
    """Progress of ``total`` steps (0: unknown total) under ``label``; see the module doc."""

    def __init__(self, total: int, label: str, unit: str = '', stream=None,
                 min_interval_s: float = 0.2, clock=time.monotonic,
                 log_pct: float = 10.0, log_s: float = 10.0):
        self.total, self.label, self.unit = int(total or 0), label, unit
        self.stream = stream if stream is not None else sys.stderr
        self.mode = mode(self.stream)
        self.on = self.mode == 'tty'
        self.min_interval_s = min_interval_s
        self.log_pct, self.log_s = log_pct, log_s
        self.clock = clock
        self.t0 = clock()
        self.done = 0
        self._t_update = self.t0                # clock of the last update
        self._last_draw: float | None = None    # clock of the last line written
        self._last_pct = 0.0                    # log mode: percent done at the last line
        self._drawn: int | None = None          # steps done at the last line
        self._width = 0                         # tty mode: width of the line on screen
        self._lock = threading.RLock()

    def _text(self, now) -> str:
        elapsed = now - self.t0
        if self.total and self.done >= self.total:
            rate = self.done / elapsed if elapsed > 0 else 0.0
            unit = f' {self.unit}' if self.unit else ''
            return (f'{self.label}: {self.done}/{self.total}{unit} (100 %), '
                    f'{format_rate(rate)}, done in {format_eta(elapsed)}')
        return line(self.label, self.done, self.total, elapsed, self.unit)

    def _pct(self) -> float:
        return 100.0 * self.done / self.total if self.total else 0.0

    def _log_due(self, now) -> bool:
        if now - self.t0 < 1.0 or (self._last_draw is not None and now - self._last_draw < 1.0):
            return False
        since = now - (self._last_draw if self._last_draw is not None else self.t0)
        return since >= self.log_s or bool(self.total
                                           and self._pct() - self._last_pct >= self.log_pct)

    def _draw(self, now):
        text = self._text(now)
        self._last_draw, self._drawn = now, self.done
        if self.mode == 'log':
            self._last_pct = self._pct()
            self.stream.write(text + '\n')
        else:
            pad = max(self._width - len(text), 0)
            self._width = len(text)
            self.stream.write('\r' + text + ' ' * pad)
        self.stream.flush()

    def update(self, done: int, total: int | None = None):
        """Set the steps done (and the total, if given); draw a line when one is due."""
        with self._lock:
            self.done = int(done)
            if total is not None:
                self.total = int(total)
            if self.mode == 'off':
                return
            now = self._t_update = self.clock()
            if self.mode == 'log':
                if self._log_due(now):
                    self._draw(now)
            elif self._last_draw is None or now - self._last_draw >= self.min_interval_s:
                self._draw(now)

    def report(self, done: int, total: int):
        """Take a ``progress(done, total)`` call (the form the cores' callbacks have)."""
        self.update(done, total)

    def advance(self, n: int = 1):
        """Add ``n`` steps done."""
        with self._lock:
            self.update(self.done + n)

    def clear(self):
        """Terminal: wipe the line (before other output); :meth:`redraw` puts it back."""
        with self._lock:
            if self.mode == 'tty' and self._width:
                self.stream.write('\r' + ' ' * self._width + '\r')
                self.stream.flush()
                self._width = 0

    def redraw(self):
        """Terminal: draw the line again now (after :meth:`clear`)."""
        with self._lock:
            if self.mode == 'tty' and self._last_draw is not None:
                self._draw(self._t_update)      # as it was: the state of the last update

    @contextlib.contextmanager
    def hidden(self):
        """Keep the terminal line out of the way while the block prints other lines."""
        with self._lock:
            self.clear()
            try:
                yield
            finally:
                self.redraw()

    def write(self, text: str, stream=None):
        """Print ``text`` as a line of its own (to ``stream``, default this one's) in any mode."""
        stream = stream if stream is not None else self.stream
        with self.hidden():
            stream.write(text + '\n')
            stream.flush()

    def note(self, text: str):
        """Print a step's progress message as :meth:`write` does, unless progress is off."""
        if self.mode != 'off':
            self.write(text)

    def close(self):
        """Draw the state of the last update and end the line.

        Nothing on a terminal where no line was drawn, nothing in a log for a job
        that took under a second.
        """
        with self._lock:
            if self.mode == 'off':
                return
            if self.mode == 'tty' and self._last_draw is None:
                return
            if self.mode == 'log' and (self._drawn == self.done
                                       or self._t_update - self.t0 < 1.0):
                return
            self._draw(self._t_update)
            if self.mode == 'tty':
                self.stream.write('\n')
                self.stream.flush()
                self._width = 0
            self._last_draw = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def track(items, label: str, unit: str = '', total: int | None = None, **kwargs):
    """Yield every item of ``items`` while a :class:`Progress` counts them (a generator)."""
    if total is None:
        total = len(items) if hasattr(items, '__len__') else 0
    with Progress(total, label, unit, **kwargs) as bar:
        for item in items:
            yield item
            bar.advance()
