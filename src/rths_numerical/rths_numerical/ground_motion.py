"""Ground motions: the seed's records, a PEER AT2 reader, scaling, resampling, baseline correction.

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

import math
import os

import numpy as np

G = 9.80665
RECORDS = {'kobe': 'Kobe', 'northridge': 'Northridge', 'imperial_valley': 'Imperial_Valley'}
#: Scale factors the seed uses (section 6.3); El Centro's 10 % is applied to Imperial Valley.
SEED_SCALES = {'imperial_valley': 0.10, 'northridge': 0.039, 'kobe': 0.135}


def _gmspy_file(name):
    import importlib.util
    spec = importlib.util.find_spec('gmspy')
    if spec is None or not spec.origin:
        raise OSError('record files need the PyPI package gmspy: pip install gmspy')
    return os.path.join(os.path.dirname(spec.origin), 'accelerograms', f'{name}.dat')


def read_gmspy_dat(path):
    """Read a gmspy ``.dat`` record; return ``(dt [s], accel [m/s^2])``."""
    try:
        data = np.loadtxt(path, skiprows=5, ndmin=2)
    except ValueError as err:
        raise ValueError(f'{path}: not two numeric columns Time[s] Accel[g] after 5 header '
                         f'lines ({err}); the file may be truncated: restore the full '
                         'record') from None
    if data.shape[0] < 2 or data.shape[1] < 2:
        raise ValueError(f'{path}: expected two columns Time[s] Accel[g] after 5 header lines')
    if not np.all(np.isfinite(data)):
        row = int(np.argwhere(~np.isfinite(data))[0, 0])
        raise ValueError(f'{path}: data line {row + 1} holds nan/inf; fix or remove it')
    t = data[:, 0]
    dt = float(np.median(np.diff(t)))
    if not dt > 0 or not np.allclose(np.diff(t), dt, rtol=1e-3, atol=1e-9):
        row = int(np.argmax(np.abs(np.diff(t) - dt))) + 1
        raise ValueError(f'{path}: time column is not equally spaced (step {dt:g} s, but data '
                         f'line {row + 1} is at {t[row]:g} s); resample the record to a '
                         'constant time step')
    return dt, data[:, 1] * G


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


def load_record(name_or_path):
    """Return ``(dt [s], accel [m/s^2])`` of 'kobe', 'northridge', 'imperial_valley' or a file.

    Files: ``.AT2`` (PEER) or the gmspy ``.dat`` layout.
    """
    key = str(name_or_path).lower()
    if key in RECORDS:
        return read_gmspy_dat(_gmspy_file(RECORDS[key]))
    path = str(name_or_path)
    if not os.path.exists(path):
        raise ValueError(f'record {name_or_path!r}: not one of {", ".join(RECORDS)} and no such '
                         'file; give a record name or the path of a PEER .AT2 file')
    if path.upper().endswith('.AT2'):
        return read_at2(path)
    return read_gmspy_dat(path)


def scale(accel, factor):
    """Return ``accel * factor`` (the seed scales records to 10 %, 3.9 %, 13.5 %)."""
    return np.asarray(accel, dtype=float) * float(factor)


def resample(accel, dt, fs_hz):
    """Resample ``accel`` sampled at ``dt`` [s] to ``fs_hz`` [Hz] (band-limited FFT method)."""
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
        from .signals import blwn
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


__all__ = ['G', 'RECORDS', 'SEED_SCALES', 'load_record', 'read_at2', 'read_gmspy_dat', 'scale',
           'resample', 'integrate', 'baseline_correct', 'ground_motion', 'peak_g']
