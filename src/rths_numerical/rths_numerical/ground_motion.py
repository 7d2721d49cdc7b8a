"""Ground motions: the seed's records, the record formats, scaling, resampling, baseline correction.

Record files are read by the format their name ends with (:data:`FORMATS`: PEER
``.AT2``, the gmspy ``.dat`` layout, or a column text file ``.csv``/``.txt`` with a
header naming ``time`` and ``accel`` with its unit, e.g. ``accel [g]``); a new format is
one reader function and one entry there (docs/extending.md).

Records (seed section 6.3: El Centro 1940 at 10 %, Northridge 1994 at 3.9 %,
Kobe 1995 at 13.5 %) come from the PyPI package ``gmspy`` which ships PEER
records as ``gmspy/accelerograms/<Name>.dat``.  Format of those files (read
here with ``numpy.loadtxt(skiprows=5)``): 5 header lines (event, source,
station, frequency range, column titles ``Time[s] Accel[g]``), then two
whitespace-separated columns: time [s] at a constant 0.01 s step and
acceleration in units of g (converted here with g = 9.80665 m/s^2).

NOTE the gmspy stations differ from the seed's: Kobe is KAKOGAWA (CUE90), not
Amagasaki; Northridge is CDMG 24278 (Castaic, 090), not Sylmar; and gmspy has
no El Centro 1940 record, only Imperial Valley 1979 (USGS 5115).  Results with
the seed's scale factors are therefore not expected to reproduce tables 6-8
in absolute terms.  Put the seed's own records in as PEER ``.AT2`` files
(:func:`read_at2`) to do that.

Baseline correction (:func:`baseline_correct`): remove the mean of the
pre-event part, then subtract a least-squares polynomial fitted to the
displacement (Newmark integration of a_g) and differentiate it twice, so the
corrected ``a_g``, ``v_g``, ``u_g`` are consistent (trapezoidal rule) and the
ground ends at rest near zero displacement.  The absolute interface frame of
:mod:`.substructure` needs that consistency.
"""

from dataclasses import dataclass, replace
import importlib.util
import math
import os
import re
from typing import Callable, NamedTuple

import numpy as np

from rths_common.columns import read_columns
from rths_common.registry import Registry
from rths_common.timebase import format_hz, same_rate, sampling_rate_hz

from .signals import blwn

G = 9.80665
RECORDS = {'kobe': 'Kobe', 'northridge': 'Northridge', 'imperial_valley': 'Imperial_Valley'}
#: Scale factors the seed uses (section 6.3); El Centro's 10 % is applied to Imperial Valley.
SEED_SCALES = {'imperial_valley': 0.10, 'northridge': 0.039, 'kobe': 0.135}


def _gmspy_file(name):
    spec = importlib.util.find_spec('gmspy')
    if spec is None or not spec.origin:
        raise OSError('record files need the PyPI package gmspy: pip install gmspy')
    return os.path.join(os.path.dirname(spec.origin), 'accelerograms', f'{name}.dat')


#: Units of a record's acceleration a user may name (header or option) -> factor to m/s^2.
ACCEL_UNITS = {'g': G, 'm/s^2': 1.0, 'm/s2': 1.0, 'cm/s^2': 0.01, 'cm/s2': 0.01, 'gal': 0.01,
               'mm/s^2': 1e-3}
#: Header name endings that carry a unit (``accel_g``, ``time_s``) -> the unit.
_SUFFIX_UNITS = {'_m_s2': 'm/s^2', '_ms2': 'm/s^2', '_cm_s2': 'cm/s^2', '_mm_s2': 'mm/s^2',
                 '_gal': 'gal', '_g': 'g', '_s': 's', '_ms': 'ms'}
_CELL = re.compile(r'^\s*(?P<name>[^\[\](){}]*?)\s*([\[(](?P<unit>[^\])]*)[\])])?\s*$')
_TIME_UNITS = {'s': 1.0, 'ms': 1e-3}


def accel_unit(unit: str, where: str) -> float:
    """Return the factor taking acceleration ``unit`` to m/s^2 (ValueError naming the units)."""
    key = str(unit).strip().lower().replace(' ', '')
    if key not in ACCEL_UNITS:
        raise ValueError(f'{where}: acceleration unit {unit!r} is not known; use g, m/s^2, '
                         'cm/s^2 or gal')
    return ACCEL_UNITS[key]


def _name_unit(cell: str):
    """Split a header cell into ``(name, unit or None)``: ``a [g]``, ``a (g)``, ``a_g``."""
    match = _CELL.match(cell)
    name, unit = (match.group('name'), match.group('unit')) if match else (cell.strip(), None)
    if unit is None:
        low = name.lower()
        for suffix, suffix_unit in _SUFFIX_UNITS.items():
            if low.endswith(suffix) and len(low) > len(suffix):
                return name[:-len(suffix)], suffix_unit
    return name, unit


def _cells(line: str):
    """Split a line at commas, else tabs, else spaces (a ``[unit]`` stays with its name)."""
    sep = ',' if ',' in line else ('\t' if '\t' in line else None)
    cells = [c.strip().strip('"').strip() for c in (line.split(sep) if sep else line.split())]
    if sep is None:
        merged: list[str] = []
        for cell in cells:
            if merged and cell[:1] in '[(':
                merged[-1] += ' ' + cell
            else:
                merged.append(cell)
        cells = merged
    return cells


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def text_layout(path):
    """Return ``(header line index or None, first data line index, header cells, data cells)``.

    Data start at the first line (not blank, not a ``#`` comment) whose cells are all
    numbers; the line before it, if any, is the header; the lines above are a preamble.
    """
    with open(path, encoding='utf-8', errors='replace') as fh:
        lines = fh.read().splitlines()
    header = None
    for i, line in enumerate(lines):
        if not line.strip() or line.lstrip().startswith('#'):
            continue
        cells = _cells(line)
        if all(_is_number(c) for c in cells):
            return header, i, (_cells(lines[header]) if header is not None else []), len(cells)
        header = i
    raise ValueError(f'{path}: no line of numbers found; a record file holds a column of '
                     'accelerations (and optionally a time column) after its header')


def _find(header, starts, what, path):
    names = [_name_unit(c)[0].strip().lower() for c in header]
    for i, name in enumerate(names):
        if name.startswith(starts):
            return i
    raise ValueError(f'{path}: no {what} column in the header ({", ".join(header)}); name it '
                     f'{" or ".join(starts)}... (e.g. time [s], accel [g])')


def read_text_record(path, units: str = '', dt_s: float = 0.0):
    """Read a column text record (CSV, tab or spaces): time and acceleration; a GroundMotion.

    Any preamble lines, then an optional header, then data.  Columns: by their
    header names (``time...`` / ``t``, ``acc...`` / ``a``), else time first and
    acceleration second.  The acceleration unit comes from the header (``accel [g]``,
    ``accel (gal)``, ``accel_m_s2``) or ``units``; neither, or both disagreeing, is
    refused.  The time unit is the header's (s or ms), else seconds.  ``dt_s``, if
    given, must match the time column.  Every data row is read: none is dropped.
    """
    head_at, data_at, header, width = text_layout(path)
    if width < 2:
        raise ValueError(f'{path}: one column of numbers: a single-column series needs its '
                         'time step (--record-dt, parameter record_dt_s)')
    if header and len(header) == width:
        i_t = _find(header, ('time', 't'), 'time', path)
        i_a = _find(header, ('acc', 'a'), 'acceleration', path)
    elif width == 2:
        i_t, i_a = 0, 1
    else:
        raise ValueError(f'{path}: {width} columns without a header naming them; write a '
                         'header such as: time [s], accel [g]')
    t_unit = _name_unit(header[i_t])[1] if header and len(header) == width else None
    a_unit = _name_unit(header[i_a])[1] if header and len(header) == width else None
    unit = _record_unit(path, a_unit, units)
    col = read_columns(path, {'time': i_t, 'accel': i_a},
                       units={'time': 's', 'accel': 'm/s^2'}, skip_lines=head_at or data_at,
                       contract='time [s], accel [UNIT]')
    factor_t = _TIME_UNITS.get(str(t_unit or 's').strip().lower())
    if factor_t is None:
        raise ValueError(f'{path}: time unit {t_unit!r}: use s or ms')
    t = col['time'] * factor_t
    fs = sampling_rate_hz(t, str(path))
    if dt_s and not same_rate(1.0 / float(dt_s), fs):
        raise ValueError(f'{path}: the time column steps {1.0 / fs:.10g} s but --record-dt '
                         f'says {dt_s:g} s; drop the option or fix the file')
    return GroundMotion(col['accel'] * accel_unit(unit, str(path)), 1.0 / fs, str(path), 'text',
                        unit, t0=float(t[0]))


def _record_unit(path, in_header, option) -> str:
    """Return the acceleration unit: the header's or the option's.

    Refused when neither names one, or when they disagree.
    """
    option = str(option or '').strip()
    if in_header and option and (accel_unit(in_header, str(path))
                                 != accel_unit(option, '--record-units')):
        raise ValueError(f'{path}: the header says the acceleration is in {in_header} but '
                         f'--record-units says {option}; drop the option or fix the header')
    unit = in_header or option
    if not unit:
        raise ValueError(f'{path}: the acceleration unit is not named; write it in the header '
                         '(accel [g], accel [m/s^2], accel_cm_s2, accel [gal]) or give '
                         '--record-units (parameter record_units): g, m/s^2, cm/s^2 or gal')
    accel_unit(unit, str(path))
    return unit


def read_series(path, units: str = '', dt_s: float = 0.0):
    """Read a single column of accelerations whose time step is ``dt_s``; a GroundMotion.

    A header line may name the unit (``accel [g]``); else ``units`` must.
    """
    head_at, data_at, header, width = text_layout(path)
    if width != 1:
        raise ValueError(f'{path}: {width} columns; a series holds one column of '
                         'accelerations (a time column makes it a text record)')
    if not dt_s or not float(dt_s) > 0 or not math.isfinite(float(dt_s)):
        raise ValueError(f'{path}: a single-column series needs its time step: give '
                         '--record-dt SECONDS (parameter record_dt_s)')
    unit = _record_unit(path, _name_unit(header[0])[1] if header else None, units)
    col = read_columns(path, {'accel': 0}, units={'accel': 'm/s^2'},
                       skip_lines=head_at if head_at is not None else data_at,
                       contract='one column of accelerations')
    return GroundMotion(col['accel'] * accel_unit(unit, str(path)), float(dt_s), str(path),
                        'series', unit)


def read_at2(path, units: str = ''):
    """Read a PEER NGA ``.AT2`` file (accelerations in g); return a :class:`GroundMotion`.

    Layout: 3 header lines, a 4th line ``NPTS= n, DT= dt SEC`` (also the old
    ``n dt`` form), then accelerations in g, several per line.
    """
    with open(path) as fh:
        lines = fh.readlines()
    if len(lines) < 5:
        raise ValueError(f'{path}: too short for a PEER AT2 file (4 header lines + data)')
    head = lines[3].upper().replace(',', ' ')
    npts = dt = None
    tokens = head.split()
    for i, tok in enumerate(tokens):
        if tok.startswith('NPTS'):
            npts = int(float(tok.split('=')[1] or tokens[i + 1]))
        if tok.startswith('DT'):
            dt = float(tok.split('=')[1] or tokens[i + 1])
    if npts is None or dt is None:
        nums = [t for t in tokens if t.replace('.', '', 1).replace('E-', '').isdigit()]
        if len(nums) >= 2:
            npts, dt = int(float(nums[0])), float(nums[1])
        else:
            raise ValueError(f'{path}: line 4 must give NPTS= and DT= (PEER AT2 header)')
    try:
        values = np.array(' '.join(lines[4:]).split(), dtype=float)
    except ValueError as err:
        raise ValueError(f'{path}: the data lines must hold numbers only ({err}); the file may '
                         'be damaged: restore it from the PEER database') from None
    if not dt > 0 or not math.isfinite(dt):
        raise ValueError(f'{path}: header DT = {dt} must be a positive time step in seconds')
    if values.size < npts:
        raise ValueError(f'{path}: header says NPTS={npts} but only {values.size} values follow; '
                         'the file is truncated: restore the full record')
    if not np.all(np.isfinite(values[:npts])):
        raise ValueError(f'{path}: the data hold nan/inf values; fix or restore the file')
    if values.size > npts:
        raise ValueError(f'{path}: header says NPTS={npts} but {values.size} values follow; '
                         'fix NPTS or the data so that they agree')
    if units and accel_unit(units, '--record-units') != G:
        raise ValueError(f'{path}: a PEER AT2 record is in g; --record-units {units} '
                         'contradicts it: drop the option')
    return GroundMotion(values[:npts] * G, dt, str(path), 'at2', 'g')


@dataclass(frozen=True)
class GroundMotion:
    """A ground motion as one value: samples, time step, where it came from, what was done.

    ``accel`` [m/s^2] at ``dt`` [s] from ``t0`` [s] (the file's first time), read from
    ``source`` by the reader ``fmt`` with the file's unit ``units``; ``processing``:
    what was done to it since, in order, as a lab engineer would write it.
    """

    accel: np.ndarray
    dt: float
    source: str
    fmt: str
    units: str
    t0: float = 0.0
    processing: tuple = ()

    def __post_init__(self):
        """Check the samples and the time step."""
        accel = np.asarray(self.accel, dtype=float).reshape(-1)
        object.__setattr__(self, 'accel', accel)
        if accel.size < 2:
            raise ValueError(f'record {self.source}: {accel.size} sample(s); a record needs '
                             'at least 2')
        if not np.all(np.isfinite(accel)):
            raise ValueError(f'record {self.source}: holds nan/inf values; fix the file')
        if not (self.dt > 0 and math.isfinite(self.dt)):
            raise ValueError(f'record {self.source}: time step {self.dt} s must be positive')

    @property
    def fs_hz(self) -> float:
        """Return the sampling rate [Hz]."""
        return 1.0 / self.dt

    @property
    def duration_s(self) -> float:
        """Return the time from the first to the last sample [s]."""
        return (self.accel.size - 1) * self.dt

    @property
    def time(self) -> np.ndarray:
        """Return the time of each sample [s] (from ``t0``)."""
        return self.t0 + np.arange(self.accel.size) * self.dt

    def peak(self) -> tuple:
        """Return ``(|peak| [m/s^2], its time [s])``."""
        i = int(np.argmax(np.abs(self.accel)))
        return float(abs(self.accel[i])), float(self.t0 + i * self.dt)

    def summary(self) -> dict:
        """Return what a lab checks before a run: samples, rate, first/last, peak (SI)."""
        peak, at = self.peak()
        return {'source': self.source, 'format': self.fmt, 'units': self.units,
                'samples': int(self.accel.size), 'dt_s': self.dt, 'fs_hz': self.fs_hz,
                't0_s': self.t0, 'duration_s': self.duration_s,
                'first_m_s2': float(self.accel[0]), 'last_m_s2': float(self.accel[-1]),
                'peak_m_s2': peak, 'peak_g': peak / G, 'peak_time_s': at,
                'processing': list(self.processing)}

    def describe(self) -> str:
        """Return the summary as lines a user reads before the run."""
        s = self.summary()
        text = (f"record {s['source']} ({s['format']}, in {s['units']}): {s['samples']} samples "
                f"at {s['fs_hz']:.10g} Hz (dt {s['dt_s']:.6g} s), {s['t0_s']:g} .. "
                f"{s['t0_s'] + s['duration_s']:.6g} s ({s['duration_s']:.6g} s); first "
                f"{s['first_m_s2']:.6g}, last {s['last_m_s2']:.6g} m/s^2; peak "
                f"{s['peak_m_s2']:.6g} m/s^2 ({s['peak_g']:.4g} g) at {s['peak_time_s']:.6g} s")
        if self.processing:
            text += '\n  processing: ' + '; '.join(self.processing)
        return text

    def replaced(self, accel, dt=None, step: str = '') -> 'GroundMotion':
        """Return this motion with new samples (and time step), ``step`` added to its processing."""
        return replace(self, accel=np.asarray(accel, dtype=float),
                       dt=self.dt if dt is None else float(dt),
                       processing=self.processing + ((step,) if step else ()))


class RecordFormat(NamedTuple):
    """A ground-motion file format: its file name endings, its reader, what it reads.

    ``read(path, **options)`` returns a :class:`GroundMotion` (or ``(dt [s], accel
    [m/s^2])``); ``options`` names the reader options it takes (``units``, ``dt_s``).
    ``accepts(path)``, if set, tells a file of a shared ending apart by its content.
    """

    summary: str
    suffixes: tuple                 # lower-case name endings, e.g. ('.at2',)
    read: Callable
    options: tuple = ()
    accepts: Callable | None = None


_TEXT = ('.csv', '.txt', '.dat', '.tsv', '.asc')


def _columns_of(path) -> int:
    return text_layout(path)[3]


#: Record file formats: name -> entry; a file is read by the entry whose suffix it ends with.
FORMATS = Registry('record format', 'format', {
    'at2': RecordFormat('PEER NGA `.AT2`: 4 header lines (`NPTS=`, `DT=`), accelerations in g',
                        ('.at2',), read_at2, ('units',)),
    'text': RecordFormat('column text (CSV, tabs or spaces; `.csv .txt .dat .tsv .asc`): '
                         'time and acceleration columns, the unit in the header (`accel [g]`, '
                         '`accel_m_s2`) or `--record-units`; any preamble lines',
                         _TEXT, read_text_record, ('units', 'dt_s'),
                         lambda path: _columns_of(path) >= 2),
    'series': RecordFormat('a single column of accelerations (same endings) with `--record-dt`; '
                           'the unit in a header line or `--record-units`',
                           _TEXT, read_series, ('units', 'dt_s'),
                           lambda path: _columns_of(path) == 1),
})


def record_format(path, name: str = '') -> RecordFormat:
    """Return the :data:`FORMATS` entry that reads ``path``: ``name``, else by ending, content."""
    if name:
        return FORMATS.entry(name, f'record {path}: record_format')
    low = str(path).lower()
    candidates = [e for e in FORMATS.values() if low.endswith(e.suffixes)]
    for entry in candidates:
        if entry.accepts is None or entry.accepts(path):
            return entry
    if candidates:
        return candidates[0]
    endings = ', '.join(sorted({s for e in FORMATS.values() for s in e.suffixes}))
    raise ValueError(f'record {path}: no reader for this file name; give a file ending in '
                     f'{endings} ({FORMATS.text(", ")}), or name the format (--record-format)')


def read_record(name_or_path, fmt: str = '', units: str = '', dt_s: float = 0.0) -> GroundMotion:
    """Read 'kobe', 'northridge', 'imperial_valley' or a record file into a GroundMotion.

    Files are read by their format (:data:`FORMATS`, by ``fmt`` or by the ending and
    content); ``units`` and ``dt_s`` go to the readers that take them, and are refused
    by the others.
    """
    key = str(name_or_path).lower()
    if key in RECORDS:
        motion = read_text_record(_gmspy_file(RECORDS[key]))
        return replace(motion, source=key)
    path = str(name_or_path)
    if not os.path.isfile(path):
        raise ValueError(f'record {name_or_path!r}: not one of {", ".join(RECORDS)} and no such '
                         f'file; give a record name or the path of a record file '
                         f'({FORMATS.text(", ")})')
    entry = record_format(path, fmt)
    given = {k: v for k, v in (('units', units), ('dt_s', dt_s)) if v}
    for option in given:
        if option not in entry.options:
            raise ValueError(f'record {path}: its format does not take {option} '
                             f'(--record-{"dt" if option == "dt_s" else option}); drop it')
    try:
        out = entry.read(path, **given)
    except UnicodeDecodeError:
        raise ValueError(f'{path}: not a text file; give a record file '
                         f'({FORMATS.text(", ")})') from None
    except ValueError as err:
        if path in str(err):
            raise
        raise ValueError(f'{path}: {err}') from None
    if isinstance(out, GroundMotion):
        return out
    dt, accel = out
    name = next(n for n, e in FORMATS.items() if e is entry)
    return GroundMotion(accel, float(dt), path, name, 'm/s^2')


def load_record(name_or_path):
    """Return ``(dt [s], accel [m/s^2])`` of a record (:func:`read_record`)."""
    motion = read_record(name_or_path)
    return motion.dt, motion.accel


def scale(accel, factor):
    """Return ``accel * factor`` (the seed scales records to 10 %, 3.9 %, 13.5 %)."""
    return np.asarray(accel, dtype=float) * float(factor)


def resample(accel, dt, fs_hz):
    """Resample ``accel`` sampled at ``dt`` [s] to ``fs_hz`` [Hz] (band-limited FFT method)."""
    # scipy.signal costs the numerical node ~0.7 s at start-up; only records are resampled
    # lazy: start-up cost: SciPy (~1 s), which this module needs only here
    from scipy.signal import resample as fft_resample

    accel = np.asarray(accel, dtype=float)
    duration = accel.size * dt
    n_new = int(round(duration * fs_hz))
    if n_new < 2:
        raise ValueError(f'resampling to {fs_hz} Hz leaves {n_new} samples')
    # pad with zeros to limit wrap-around (records start and end near zero), to a length whose
    # duration is a whole number of new samples: sample j is then exactly at j / fs_hz
    pad = accel.size // 8
    for extra in range(2000):
        if abs((accel.size + pad + extra) * dt * fs_hz % 1.0 - 0.5) > 0.5 - 1e-9:
            pad += extra
            break
    x = np.concatenate([accel, np.zeros(pad)])
    y = fft_resample(x, int(round(x.size * dt * fs_hz)))
    return y[:n_new]


def integrate(accel, dt):
    """Ground velocity and displacement by the trapezoidal rule (average acceleration)."""
    a = np.asarray(accel, dtype=float)
    v = np.concatenate([[0.0], np.cumsum(0.5 * dt * (a[1:] + a[:-1]))])
    u = np.concatenate([[0.0], np.cumsum(0.5 * dt * (v[1:] + v[:-1]))])
    return v, u


def baseline_correct(accel, dt, order=3, pre_s=0.0):
    """Return ``(a, v, u)`` baseline-corrected and mutually consistent (trapezoidal rule).

    Removes the pre-event mean (first ``pre_s`` s, or the record mean if 0),
    then a polynomial of ``order`` (>= 2, no constant/linear terms) fitted to the
    displacement, differentiated twice and removed from the acceleration; the
    final ``v``, ``u`` are re-integrated from the corrected acceleration.
    """
    a = np.asarray(accel, dtype=float).copy()
    n = a.size
    m = max(1, int(round(pre_s / dt))) if pre_s > 0 else n
    a -= a[:m].mean()
    a = remove_cubic_baseline(a, dt, order)
    v, u = integrate(a, dt)
    return a, v, u


class Processing(NamedTuple):
    """What may be done to a record before the run, each switchable off."""

    resample: bool = True      # to the loop rate (band-limited FFT); off: rates must agree
    remove_mean: bool = True   # subtract the record's mean acceleration
    baseline: bool = True      # remove a cubic polynomial fitted to the ground displacement


#: Every processing step on (the default).
ALL_PROCESSING = Processing()


def prepare(motion: GroundMotion, fs_hz: float, scale_factor: float = 1.0,
            duration_s: float | None = None, processing: Processing = ALL_PROCESSING):
    """Return ``(motion at fs_hz, ground displacement [m])`` with every step it took stated.

    In order: scaling, resampling to the loop rate, trimming or zero-padding to
    ``duration_s``, mean removal, baseline correction; each step done (or switched
    off) is named in the result's ``processing``.  The displacement is the trapezoidal
    double integral of the final acceleration (what the absolute frame needs).
    """
    fs = float(fs_hz)
    out = motion.replaced(scale(motion.accel, scale_factor), step=f'scaled x {scale_factor:g}')
    if same_rate(out.fs_hz, fs):
        out = out.replaced(out.accel, 1.0 / fs, 'at the loop rate: not resampled')
    elif processing.resample:
        out = out.replaced(resample(out.accel, out.dt, fs), 1.0 / fs,
                           f'resampled {format_hz(out.fs_hz)} -> {format_hz(fs)} Hz '
                           '(band-limited FFT)')
    else:
        raise ValueError(f'record {motion.source}: sampled at {format_hz(out.fs_hz)} Hz, the '
                         f'loop runs at {format_hz(fs)} Hz and resampling is off '
                         '(record_resample: false); resample the record to the loop rate or '
                         'switch resampling on')
    if duration_s:
        n = int(round(duration_s * fs))
        step = (f'trimmed to {duration_s:g} s' if n <= out.accel.size
                else f'zero-padded to {duration_s:g} s')
        out = out.replaced(np.concatenate([out.accel, np.zeros(max(0, n - out.accel.size))])[:n],
                           step=step)
    a = out.accel.copy()
    if processing.remove_mean:
        mean = float(a.mean())
        a -= mean
        out = out.replaced(a, step=f'mean removed ({mean:.4g} m/s^2)')
    else:
        out = out.replaced(a, step='mean kept (mean removal off)')
    if processing.baseline:
        before = float(np.max(np.abs(a))) or 1.0
        a = remove_cubic_baseline(a, out.dt)
        change = 100.0 * (float(np.max(np.abs(a))) / before - 1.0)
        out = out.replaced(a, step='baseline corrected: a cubic polynomial fitted to the '
                           f'displacement removed (peak {change:+.3f} %)')
    else:
        out = out.replaced(a, step='no baseline correction (off)')
    return out, integrate(out.accel, out.dt)[1]


def remove_cubic_baseline(accel, dt, order=3):
    """Return ``accel`` less the second derivative of a polynomial fitted to its displacement.

    The polynomial has powers 2..``order`` (no constant or linear term), fitted by
    least squares to the trapezoidal double integral of ``accel``.
    """
    a = np.asarray(accel, dtype=float).copy()
    _, u = integrate(a, dt)
    t = np.arange(a.size) * dt
    powers = np.arange(2, max(order, 2) + 1)
    coef, *_ = np.linalg.lstsq(t[:, None] ** powers[None, :], u, rcond=None)
    return a - (t[:, None] ** (powers - 2)[None, :] * (powers * (powers - 1))[None, :]) @ coef


def ground_motion(record, fs_hz, scale_factor=1.0, duration_s=None, rng=None, blwn_band_hz=10.0,
                  blwn_peak=1.0):
    """Return the ground acceleration [m/s^2] at ``fs_hz`` for a record name/path or 'blwn'/'none'.

    ``duration_s`` trims or zero-pads (records) or sets the length (BLWN,
    peak ``blwn_peak * scale_factor`` in g over 0..``blwn_band_hz`` Hz).
    """
    if record == 'none':
        n = int(round((duration_s or 0.0) * fs_hz))
        return np.zeros(n)
    if record == 'blwn':
        if not duration_s:
            raise ValueError('duration_s must be > 0 for record blwn')
        return blwn(duration_s, fs_hz, blwn_band_hz, blwn_peak * G * scale_factor, rng=rng)
    dt, acc = load_record(record)
    acc = resample(scale(acc, scale_factor), dt, fs_hz)
    if duration_s:
        n = int(round(duration_s * fs_hz))
        acc = np.concatenate([acc, np.zeros(max(0, n - acc.size))])[:n]
    return acc


def peak_g(accel):
    """Peak absolute acceleration in g."""
    return float(np.max(np.abs(accel)) / G) if len(accel) else 0.0


__all__ = ['G', 'RECORDS', 'SEED_SCALES', 'FORMATS', 'GroundMotion', 'Processing', 'prepare',
           'read_record', 'load_record', 'read_at2', 'read_text_record', 'read_series',
           'record_format', 'scale', 'remove_cubic_baseline',
           'resample', 'integrate', 'baseline_correct', 'ground_motion', 'peak_g']
