"""The linear baseline: the best linear model a record supports, before any effect is named.

A discrepancy is only what a *good* linear model misses, so the baseline is fitted
as system identification knows how, on any uniform rate and in any units (every
criterion below is relative to the record's own band, spread and length):

* Band.  ``f_in`` = the input's band edge (99.9 % of its power).  A record sampled
  far above it is decimated by ``q = floor(fs / (OVERSAMPLE f_in))`` (zero-phase
  polyphase resampling, scipy ``resample_poly``) so that an ARX of moderate order
  spans the band; the model's response is resampled back to ``fs``.
* Orders from the data.  The ARX grid of the project's identification
  (:func:`rths_compensator.identification.arx_grid`: na 1..NA_MAX, nb 1..NB_MAX,
  dead time 0..D_MAX) is scored by *simulation* error on a validation part (the last
  ``VALIDATION`` of each training record) and the BIC winner is refitted on the
  whole training data.
* Output error.  The ARX winner starts Steiglitz-McBride iterations (the ARX refitted
  on the data filtered by ``1 / A``: the equation error tends to the simulation
  error, an output-error model of the same orders); the best iterate replaces the
  ARX if it simulates the validation part better.
* Offsets.  The model maps deviations from the training means: ``y = y0 + G (u - u0)``.
* Reference.  :func:`arx_reference` is the plain ARX of the same identification
  at the record's own rate (BIC, simulation error): reported beside the baseline so
  that a bad baseline cannot pass as a discrepancy.

Derivatives (restoring force).  :func:`spectral_derivative` differentiates in the
frequency domain (exact for a band-limited signal: no central-difference gain loss
near the band edge).  A periodic record is differentiated over its whole periods;
any other record after removing the straight line through its end points (so its
periodic extension is continuous) and with a raised-cosine low-pass from ``fc`` to
``1.25 fc`` -- the stated smoothing differentiator; its end effects stay in the
first and last few per cent, which the scenarios leave out of every fit.
"""

import dataclasses

import numpy as np
from scipy import signal

from rths_compensator import identification as idf

#: Decimate until fs is about this many times the input's band edge.
OVERSAMPLE = 5.0
NA_MAX = 30
NB_MAX = 30
D_MAX = 2
#: Fraction at the end of each training record that validates the orders.
VALIDATION = 0.3
#: Relative ridge of the ARX normal equations (band-limited lag regressions are near-singular).
RIDGE = 1e-10
#: Orders of the plain reference ARX at the record's own rate.
REF_MAX = 12


def band_edge(y, fs, fraction=0.999):
    """Frequency [Hz] below which ``fraction`` of the power of ``y`` (mean removed) lies."""
    y = np.asarray(y, float) - np.mean(y)
    p = np.abs(np.fft.rfft(y)) ** 2
    c = np.cumsum(p)
    f = np.fft.rfftfreq(y.size, 1.0 / fs)
    if c[-1] <= 0:
        return fs / 8
    return float(f[min(np.searchsorted(c, fraction * c[-1]), f.size - 1)])


def decimation(u, fs):
    """Decimation factor ``q`` of a record with input ``u`` sampled at ``fs``."""
    return max(1, int(fs / (OVERSAMPLE * max(band_edge(u, fs), 1e-12 * fs))))


def _down(x, q):
    return x if q == 1 else signal.resample_poly(x, 1, q, padtype='line')


def _up(x, q, n):
    if q == 1:
        return x[:n]
    y = signal.resample_poly(x, q, 1, padtype='line')
    return y[:n] if y.size >= n else np.r_[y, np.full(n - y.size, y[-1])]


@dataclasses.dataclass
class LinearModel:
    """A linear model at decimation ``q`` of ``fs``: ``y = y0 + G (u - u0)``."""

    arx: idf.ArxModel
    q: int
    fs: float
    u0: float
    y0: float
    method: str

    def simulate(self, u):
        """Free-run response to ``u`` (from rest at the offsets), at the record's rate."""
        u = np.asarray(u, float)
        return self.y0 + _up(self.arx.simulate(_down(u - self.u0, self.q)), self.q, u.size)

    def describe(self):
        """Plain dict of the model (orders, rate, method)."""
        return {'method': self.method, 'na': self.arx.na, 'nb': self.arx.nb, 'd': self.arx.d,
                'decimation': self.q, 'model_rate_hz': self.fs / self.q,
                'stable': bool(self.arx.is_stable())}


def _split(records):
    """Training and validation parts of each (u, y) record."""
    tr, va = [], []
    for u, y in records:
        k = int((1 - VALIDATION) * u.size)
        tr.append((u[:k], y[:k]))
        va.append((u[k:], y[k:]))
    return tr, va


def _grid(train, val, fs, na_max, nb_max, d_max):
    n_min = min(u.size for u, _ in train + val)
    cap = max(1, n_min // 12)     # the regression needs a few rows per lag
    na_max, nb_max = min(na_max, cap), min(nb_max, cap)
    g = idf.arx_grid(train, val, range(1, na_max + 1), range(1, nb_max + 1),
                     range(0, d_max + 1), fs_hz=fs, error='simulation', ridge=RIDGE)
    return idf.model_from_grid(g, 'bic')


def _sim_error(model, records):
    e = [y - model.simulate(u) for u, y in records]
    return float(np.mean(np.concatenate(e) ** 2))


def _output_error(arx, records, iterations=8):
    """Refine ``arx`` by Steiglitz-McBride iterations; return the iterate simulating best.

    Each iteration refits the ARX on the records filtered by ``1 / A`` of the previous
    model, which drives the equation error towards the simulation (output) error.
    """
    best, best_err = arx, _sim_error(arx, records)
    a = arx.a
    for _ in range(iterations):
        filt = [(signal.lfilter([1.0], a, u), signal.lfilter([1.0], a, y)) for u, y in records]
        try:
            cand = idf.fit_arx(filt, arx.na, arx.nb, arx.d, arx.fs_hz, ridge=RIDGE)
        except ValueError:
            break
        if not cand.is_stable():
            break
        err = _sim_error(cand, records)
        if err < best_err:
            best, best_err = cand, err
        a = cand.a
    return best


def fit(records, fs, progress=None):
    """Identify the linear baseline from training ``records`` [(u, y), ...] at ``fs``.

    Returns a :class:`LinearModel`; ``progress(text)`` gets the steps.
    """
    say = progress or (lambda text: None)
    u0 = float(np.mean(np.concatenate([u for u, _ in records])))
    y0 = float(np.mean(np.concatenate([y for _, y in records])))
    q = decimation(np.concatenate([u for u, _ in records]), fs)
    dec = [(_down(u - u0, q), _down(y - y0, q)) for u, y in records]
    tr, va = _split(dec)
    arx = _grid(tr, va, fs / q, NA_MAX, NB_MAX, D_MAX)
    arx = idf.fit_arx(dec, arx.na, arx.nb, arx.d, fs / q, ridge=RIDGE)
    best = LinearModel(arx, q, fs, u0, y0, 'arx')
    say(f'linear baseline: decimation {q} (model rate {fs / q:.4g} Hz), ARX na={arx.na} '
        f'nb={arx.nb} d={arx.d} by simulation error and BIC')
    arx_tr = idf.fit_arx(tr, arx.na, arx.nb, arx.d, fs / q, ridge=RIDGE)
    oe = _output_error(arx_tr, tr)
    if oe is not arx_tr and _sim_error(oe, va) < _sim_error(arx_tr, va):
        oe = _output_error(oe, dec, iterations=2)
        best = LinearModel(oe, q, fs, u0, y0, 'output-error')
        say('linear baseline: the output-error refinement (Steiglitz-McBride) simulates the '
            'validation part better; kept')
    return best


def arx_reference(records, fs):
    """Return the plain ARX of the project's identification at the record's own rate (BIC)."""
    u0 = float(np.mean(np.concatenate([u for u, _ in records])))
    y0 = float(np.mean(np.concatenate([y for _, y in records])))
    cen = [(u - u0, y - y0) for u, y in records]
    tr, va = _split(cen)
    arx = _grid(tr, va, fs, REF_MAX, REF_MAX, D_MAX)
    arx = idf.fit_arx(cen, arx.na, arx.nb, arx.d, fs, ridge=RIDGE)
    return LinearModel(arx, 1, fs, u0, y0, 'arx-reference')


# ---------------------------------------------------------------- derivatives

def period(u, min_periods=2, tol=1e-3):
    """Return the samples per period of a periodic record ``u`` (None if it does not repeat).

    A period P is accepted when the record holds at least ``min_periods`` of them and
    ``u[k + P] - u[k]`` is below ``tol`` of the spread of ``u`` in rms.
    """
    u = np.asarray(u, float) - np.mean(u)
    n = u.size
    if n < 8 or np.std(u) == 0:
        return None
    spec = np.fft.rfft(u, 2 * n)
    ac = np.fft.irfft(np.abs(spec) ** 2)[:n // min_periods + 1]
    ac /= ac[0]
    lags = np.flatnonzero((ac[1:-1] > ac[:-2]) & (ac[1:-1] >= ac[2:]) & (ac[1:-1] > 0.5)) + 1
    for p in lags:
        if p >= 4 and np.sqrt(np.mean((u[p:] - u[:-p]) ** 2)) < tol * np.std(u):
            return int(p)
    return None


def spectral_derivative(y, fs, order=1, fc=None):
    """``order``-th time derivative of ``y`` by spectral differentiation (see module doc).

    ``fc`` [Hz] (None: no low-pass) is the edge of the raised-cosine taper that
    ends at ``1.25 fc``.
    """
    y = np.asarray(y, float)
    n = y.size
    t = np.arange(n)
    line = y[0] + (y[-1] - y[0]) * t / max(n - 1, 1)
    r = y - line
    f = np.fft.rfftfreq(n, 1.0 / fs)
    h = (2j * np.pi * f) ** order
    if n % 2 == 0 and order % 2 == 1:
        h[-1] = 0.0     # the Nyquist line has no defined odd derivative
    if fc is not None:
        w = np.clip((f - fc) / (0.25 * fc), 0.0, 1.0)
        h = h * 0.5 * (1 + np.cos(np.pi * w))
    d = np.fft.irfft(np.fft.rfft(r) * h, n)
    if order == 0:
        d += line
    elif order == 1:
        d += (y[-1] - y[0]) * fs / max(n - 1, 1)
    return d


def spectral_states(x, fs, fc):
    """Displacement, velocity, acceleration of ``x`` band-limited to ``fc`` (spectral)."""
    return {'x': spectral_derivative(x, fs, 0, fc), 'v': spectral_derivative(x, fs, 1, fc),
            'a': spectral_derivative(x, fs, 2, fc)}
