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

import importlib.util
import math
import os
from typing import Callable, NamedTuple

import numpy as np

from rths_common.columns import read_columns
from rths_common.registry import Registry
from rths_common.timebase import sampling_rate_hz

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


def read_gmspy_dat(path):
    """Read a gmspy ``.dat`` record; return ``(dt [s], accel [m/s^2])``."""
    try:
        col = read_columns(path, {'time': 0, 'accel': 1}, units={'time': 's', 'accel': 'g'},
                           skip_lines=5, contract='Time[s] Accel[g] after 5 header lines')
    except ValueError as err:
        raise ValueError(f'{err} (expected two numeric columns Time[s] Accel[g] after 5 header '
                         'lines; the file may be truncated: restore the full record)') from None
    t = col['time']
    dt = float(np.median(np.diff(t)))
    if not dt > 0 or not np.allclose(np.diff(t), dt, rtol=1e-3, atol=1e-9):
        row = int(np.argmax(np.abs(np.diff(t) - dt))) + 1
        raise ValueError(f'{path}: time column is not equally spaced (step {dt:g} s, but data '
                         f'line {row + 1} is at {t[row]:g} s); resample the record to a '
                         'constant time step')
    return 1.0 / sampling_rate_hz(t, str(path)), col['accel']


def read_csv_record(path):
    """Read a column text record; return ``(dt [s], accel [m/s^2])``.

    The header names ``time`` and ``accel``, each with its unit in brackets
    (``time [s], accel [g]``); the acceleration is converted to m/s^2 from it.
    """
    col = read_columns(path, ('time', 'accel'), require_units=True,
                       contract='time [s], accel [UNIT] (UNIT: g, m/s^2, gal, ...)')
    return 1.0 / sampling_rate_hz(col['time'], str(path)), col['accel']


def read_at2(path):
    """Read a PEER NGA ``.AT2`` file; return ``(dt [s], accel [m/s^2])``.

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
    return dt, values[:npts] * G


class RecordFormat(NamedTuple):
    """A ground-motion file format: its file name endings and its reader."""

    summary: str
    suffixes: tuple                 # lower-case name endings, e.g. ('.at2',)
    read: Callable                  # path -> (dt [s], accel [m/s^2])


#: Record file formats: name -> entry; a file is read by the entry whose suffix it ends with.
FORMATS = Registry('record format', 'format', {
    'at2': RecordFormat('PEER NGA `.AT2`: 4 header lines (`NPTS=`, `DT=`), accelerations in g',
                        ('.at2',), read_at2),
    'gmspy': RecordFormat('gmspy `.dat`: 5 header lines, columns Time [s] and Accel [g]',
                          ('.dat',), read_gmspy_dat),
    'csv': RecordFormat('column text `.csv`/`.txt` with a header `time [s], accel [UNIT]` '
                        '(UNIT g, m/s^2, gal, ...)', ('.csv', '.txt'), read_csv_record),
})


def record_format(path) -> RecordFormat:
    """Return the :data:`FORMATS` entry that reads ``path`` (ValueError naming the endings)."""
    name = str(path).lower()
    for entry in FORMATS.values():
        if name.endswith(entry.suffixes):
            return entry
    endings = ', '.join(s for e in FORMATS.values() for s in e.suffixes)
    raise ValueError(f'record {path}: no reader for this file name; give a file ending in '
                     f'{endings} ({FORMATS.text(", ")})')


def load_record(name_or_path):
    """Return ``(dt [s], accel [m/s^2])`` of 'kobe', 'northridge', 'imperial_valley' or a file.

    Files are read by their format (:data:`FORMATS`, by the name's ending).
    """
    key = str(name_or_path).lower()
    if key in RECORDS:
        return read_gmspy_dat(_gmspy_file(RECORDS[key]))
    path = str(name_or_path)
    if not os.path.exists(path):
        raise ValueError(f'record {name_or_path!r}: not one of {", ".join(RECORDS)} and no such '
                         f'file; give a record name or the path of a record file '
                         f'({FORMATS.text(", ")})')
    try:
        return record_format(path).read(path)
    except UnicodeDecodeError:
        raise ValueError(f'{path}: not a text file; give a record file '
                         f'({FORMATS.text(", ")})') from None
    except ValueError as err:
        if path in str(err):
            raise
        raise ValueError(f'{path}: {err}') from None


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
    # pad with zeros to limit wrap-around (records start and end near zero)
    pad = accel.size // 8
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
    _, u = integrate(a, dt)
    t = np.arange(n) * dt
    powers = np.arange(2, max(order, 2) + 1)
    basis = t[:, None] ** powers[None, :]
    coef, *_ = np.linalg.lstsq(basis, u, rcond=None)
    a -= (t[:, None] ** (powers - 2)[None, :] * (powers * (powers - 1))[None, :]) @ coef
    v, u = integrate(a, dt)
    return a, v, u


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


__all__ = ['G', 'RECORDS', 'SEED_SCALES', 'FORMATS', 'load_record', 'read_at2', 'read_gmspy_dat',
           'read_csv_record', 'record_format', 'scale',
           'resample', 'integrate', 'baseline_correct', 'ground_motion', 'peak_g']
