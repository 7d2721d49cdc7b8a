"""Sampling rates: inferring one from a time column, and comparing rates as they are written.

A record's time column is printed with finite precision (the project's CSV writer uses 10
significant digits, other tools 6 decimals), so the step between two rows is not the sampling
period: 1/median(diff(t)) of a 1024 Hz record printed with 6 decimals is 1023.54 Hz. Here:

- :func:`infer_rate` fits ``t = t0 + k / fs`` over the whole record (least squares), then
  snaps ``fs`` to the rate with the fewest significant digits that reproduces every printed
  time to within its printed precision (half a unit in its last digit). A 1024 Hz record
  written with 6 to 10 significant digits gives 1024 exactly; a record whose times fit no
  short rate keeps the fitted one. :func:`sampling_rate_hz` returns just the number.
- :func:`same_rate` compares two rates with the tolerance of how rates are printed (six
  significant digits, ``%g``): two rates that print alike are one rate. :func:`nominal_rate`
  gives the shortest rate within that tolerance (1024.000524 -> 1024); :func:`format_hz`
  prints a rate with enough digits to tell two rates that are not the same apart.
"""

from dataclasses import dataclass

import numpy as np

#: Relative tolerance of a rate: rates are printed with six significant digits (``%g``),
#: so rates closer than one part in 10^6 print alike and are one rate.
RATE_RTOL = 1e-6

#: Largest step-to-step deviation from the fitted period, as a fraction of the period (beyond
#: the printed precision), before a time column counts as not uniformly sampled.
UNIFORM_RTOL = 0.01

#: Rows either side whose printed digits tell a row's precision in the uniformity check.
UNIT_WINDOW = 4

_MAX_DECIMALS = 17
_MAX_DIGITS = 12


@dataclass(frozen=True)
class RateEstimate:
    """A sampling rate inferred from a time column.

    ``fs_hz`` is the rate to use: ``fitted_hz`` snapped to the printed precision when
    ``snapped``. ``resolution_s`` is the coarsest printed step of the times (the unit in
    their last digit), ``samples`` the number of rows.
    """

    fs_hz: float
    fitted_hz: float
    resolution_s: float
    samples: int
    snapped: bool

    def __str__(self) -> str:
        how = (f'the rate the times printed to {self.resolution_s:.0e} s imply (fit '
               f'{self.fitted_hz:.10g} Hz)' if self.snapped else
               'fitted; no shorter rate reproduces the printed times')
        return f'{self.fs_hz:.10g} Hz over {self.samples} samples, {how}'


def infer_rate(time, where: str = 'time') -> RateEstimate:
    """Infer the sampling rate of a uniformly sampled ``time`` column [s].

    Raises ValueError (naming ``where``) for fewer than 2 rows, non-finite or
    non-increasing times, or steps that deviate from the fitted period by more than
    ``UNIFORM_RTOL`` of it plus the printed precision.
    """
    t = np.asarray(time, dtype=float).ravel()
    if t.size < 2:
        raise ValueError(f'{where}: column time needs at least 2 rows to give a sampling rate')
    if not np.all(np.isfinite(t)):
        raise ValueError(f'{where}: column time holds nan/inf values')
    dt = np.diff(t)
    if np.any(dt <= 0):
        i = int(np.argmax(dt <= 0))
        raise ValueError(f'{where}: column time is not increasing at row {i + 1} '
                         f'({t[i]:.10g} -> {t[i + 1]:.10g} s)')
    k = np.arange(t.size, dtype=float)
    period, period_se = _fit_period(k, t)
    unit = _printed_unit(t)
    ulp = 8 * np.spacing(np.abs(t))
    tol = 0.5 * unit + ulp
    # a row whose last digits happen to be zeros looks coarser than it was printed: for the
    # step check its neighbours' finer digits tell the precision (the column's format)
    near = 0.5 * _neighbourhood_unit(unit, t, UNIT_WINDOW) + ulp
    dev = np.abs(dt - period) - near[:-1] - near[1:]
    if np.max(dev) > UNIFORM_RTOL * period:
        i = int(np.argmax(dev))
        raise ValueError(f'{where}: column time is not uniformly sampled (step {dt[i]:.6g} s '
                         f'at row {i + 1}, period {period:.6g} s over the record); resample '
                         'the record to a uniform rate')
    fitted = 1.0 / period
    spread = max(0.5 * RATE_RTOL * fitted, 4 * period_se * fitted ** 2)
    snapped = _snap(fitted, spread, k, t, tol)
    return RateEstimate(fs_hz=fitted if snapped is None else snapped, fitted_hz=fitted,
                        resolution_s=float(np.sort(unit)[(unit.size - 1) // 2]),
                        samples=int(t.size), snapped=snapped is not None)


def sampling_rate_hz(time, where: str = 'time') -> float:
    """Return the sampling rate [Hz] of a uniformly sampled ``time`` column (:func:`infer_rate`)."""
    return infer_rate(time, where).fs_hz


def same_rate(a: float, b: float) -> bool:
    """Tell whether rates ``a`` and ``b`` [Hz] agree within ``RATE_RTOL`` (print alike)."""
    a, b = float(a), float(b)
    return abs(a - b) <= RATE_RTOL * max(abs(a), abs(b))


def format_hz(fs_hz: float) -> str:
    """Print ``fs_hz`` with up to 10 significant digits (1024, 1024.000524)."""
    return f'{float(fs_hz):.10g}'


def nominal_rate(fs_hz: float) -> float:
    """Return the rate of fewest significant digits that is :func:`same_rate` as ``fs_hz``."""
    fs = float(fs_hz)
    for digits in range(1, _MAX_DIGITS + 1):
        candidate = float(f'{fs:.{digits}g}')
        if same_rate(candidate, fs):
            return candidate
    return fs


def _fit_period(k, t):
    """Least-squares slope of ``t`` over the row index ``k`` and its standard error [s]."""
    kc, tc = k - k.mean(), t - t.mean()
    skk = float(np.dot(kc, kc))
    slope = float(np.dot(kc, tc) / skk)
    if t.size < 3:
        return slope, 0.0
    resid = tc - slope * kc
    return slope, float(np.sqrt(np.dot(resid, resid) / (t.size - 2) / skk))


def _neighbourhood_unit(unit, t, half: int):
    """Return, for each row, the finest ``unit`` of the rows within ``half`` of it.

    Only rows of the same order of magnitude count: a format with significant digits
    (``%g``) prints 9.99999 to 1e-5 but 10.0001 to 1e-4.
    """
    decade = np.floor(np.log10(np.maximum(np.abs(t), np.finfo(float).tiny)))
    window = 2 * half + 1
    units = np.lib.stride_tricks.sliding_window_view(np.pad(unit, half, mode='edge'), window)
    decades = np.lib.stride_tricks.sliding_window_view(np.pad(decade, half, mode='edge'),
                                                       window)
    same = decades == decade[:, None]
    return np.where(same, units, np.inf).min(axis=1)


def _printed_unit(t):
    """Return the unit in the last printed digit of each time [s].

    A time's printed precision is the fewest decimals that reproduce it; a trailing zero
    makes it look coarser, which only loosens that one row.
    """
    scale = np.maximum(np.abs(t), np.finfo(float).tiny)
    unit = np.full(t.shape, 10.0 ** -_MAX_DECIMALS)
    found = np.zeros(t.shape, dtype=bool)
    for decimals in range(_MAX_DECIMALS + 1):
        q = 10.0 ** -decimals
        exact = np.abs(t - np.round(t / q) * q) <= 4 * np.spacing(scale) + 1e-3 * q
        unit[exact & ~found] = q
        found |= exact
    return unit


def _snap(fitted: float, spread: float, k, t, tol):
    """Return the shortest rate within ``spread`` of ``fitted`` reproducing every printed time.

    A rate reproduces the times when some start time t0 puts every ``t0 + k / fs`` within
    the printed tolerance of its row: the intervals ``[t - k/fs - tol, t - k/fs + tol]``
    intersect. None if no rate of up to 12 significant digits does.
    """
    for digits in range(1, _MAX_DIGITS + 1):
        candidate = float(f'{fitted:.{digits}g}')
        if candidate <= 0 or abs(candidate - fitted) > spread:
            continue
        r = t - k / candidate
        if np.max(r - tol) <= np.min(r + tol):
            return candidate
    return None
