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
  ``VALIDATION`` of each training record, simulated after the input before it, so
  from the state the system was in, not from rest) and the BIC winner (the fewest
  parameters among orders within ``BIC_TIE`` of the best) is refitted on the whole
  training data.
* Output error.  The ARX winner starts Steiglitz-McBride iterations (the ARX refitted
  on the data filtered by ``1 / A``: the equation error tends to the simulation
  error, an output-error model of the same orders); the best iterate replaces the
  ARX if it simulates the validation part better.
* Offsets.  The model maps deviations from the training means: ``y = y0 + G (u - u0)``.
* Reference.  :func:`arx_reference` is the plain ARX of the same identification
  at the record's own rate (BIC, simulation error): reported beside the baseline so
  that a bad baseline cannot pass as a discrepancy.

Derivatives (spectral differentiation, the period of a record) live in :mod:`.signals`.
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
#: BIC difference (validation samples' units) below which two order sets are not told
#: apart by the data (Raftery 1995: "not worth more than a bare mention"); the fewer
#: parameters win.
BIC_TIE = 2.0
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
    """Training parts and validation records ``(u, y, k)`` of each (u, y) record.

    A validation record is the whole record scored from sample ``k`` on: the model is
    simulated through the training part, so the validation part starts in the state the
    input brought the system to (from rest, the start-up transient of a lightly damped
    model was scored as its error and chose the orders).
    """
    tr, va = [], []
    for u, y in records:
        k = int((1 - VALIDATION) * u.size)
        tr.append((u[:k], y[:k]))
        va.append((u, y, k))
    return tr, va


def _grid(train, val, fs, na_max, nb_max, d_max):
    n_min = min([u.size for u, _ in train] + [u.size - k for u, _, k in val])
    cap = max(1, n_min // 12)     # the regression needs a few rows per lag
    na_max, nb_max = min(na_max, cap), min(nb_max, cap)
    g = idf.arx_grid(train, [(u, y) for u, y, _ in val], range(1, na_max + 1),
                     range(1, nb_max + 1), range(0, d_max + 1), fs_hz=fs, error='simulation',
                     ridge=RIDGE, warmup=[k for _, _, k in val])
    # BIC in units of the validation samples (n ln mse + p ln n, summed over records);
    # orders within BIC_TIE of the best are not told apart by the data: the fewest
    # parameters among them (parsimony), so a lag more or less does not hang on noise
    nv = np.array([float(u.size - k) for u, _, k in val])[:, None]
    with np.errstate(invalid='ignore'):
        total = np.sum(np.where(np.isfinite(g['scores']['bic']), g['scores']['bic'], np.inf) * nv,
                       axis=0)
    if not np.any(np.isfinite(total)):
        return idf.model_from_grid(g, 'bic')
    dim = g['orders'][:, 0] + g['orders'][:, 1]
    tied = np.flatnonzero(total <= np.min(total) + BIC_TIE)
    k = int(min(tied, key=lambda i: (dim[i], total[i])))
    na, nb, d = (int(v) for v in g['orders'][k])
    theta = g['thetas'][k]
    return idf.ArxModel(a=np.r_[1.0, theta[:na]], b=theta[na:], d=d, fs_hz=fs)


def _sim_error(model, records):
    """Mean squared simulation error over ``(u, y)`` or ``(u, y, k)`` (scored from ``k``)."""
    e = [(r[1] - model.simulate(r[0]))[(r[2] if len(r) > 2 else 0):] for r in records]
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


def least_squares(mat, target):
    """Least-squares solution of ``mat theta = target`` on unit-scaled columns (``lstsq``)."""
    mat = np.asarray(mat, float)
    scale = np.std(mat, axis=0)
    scale[scale == 0] = 1.0
    return np.linalg.lstsq(mat / scale, target, rcond=None)[0] / scale


def _masked_fit(records, keep, na, nb, d, fs, a_filter):
    """ARX of orders (na, nb, d) on the rows whose output and lagged outputs ``keep`` marks."""
    phis, tgs = [], []
    for (u, y), k in zip(records, keep, strict=True):
        phi, tg = idf._regression(signal.lfilter([1.0], a_filter, u),
                                  signal.lfilter([1.0], a_filter, y), na, nb, d)
        rows = np.arange(y.size - tg.size, y.size)
        ok = np.lib.stride_tricks.sliding_window_view(k, na + 1)[rows - na].all(axis=1)
        phis.append(phi[ok][:, list(range(na)) + list(range(na + d, na + d + nb))])
        tgs.append(tg[ok])
    theta = least_squares(np.vstack(phis), np.concatenate(tgs))
    return idf.ArxModel(a=np.r_[1.0, theta[:na]], b=theta[na:], d=d, fs_hz=fs)


def refit_where(base, records, keep, iterations=4):
    """Refit ``base``'s orders on the samples ``keep`` marks (e.g. off a saturation plateau).

    ``records`` [(u, y), ...] at the base's rate and ``keep`` one boolean array per
    record.  An output on a plateau says nothing about the linear dynamics: a row of
    the regression is used only if the output it predicts and its lagged outputs are
    kept.  Equation error first, then Steiglitz-McBride iterations; the iterate
    simulating the kept samples best is returned as a :class:`LinearModel`.
    """
    q, arx = base.q, base.arx
    dec = [(_down(u - base.u0, q), _down(y - base.y0, q)) for u, y in records]
    kd = [_down(np.asarray(k, float), q) > 0.99 for k in keep]

    def err(m):
        lm = LinearModel(m, q, base.fs, base.u0, base.y0, 'off-plateau')
        e = [(y - lm.simulate(u))[k] for (u, y), k in zip(records, keep, strict=True)]
        return float(np.mean(np.concatenate(e) ** 2))

    best, best_err, a = None, np.inf, np.array([1.0])
    for _ in range(iterations + 1):
        try:
            m = _masked_fit(dec, kd, arx.na, arx.nb, arx.d, base.fs / q, a)
        except (ValueError, np.linalg.LinAlgError):
            break
        if not m.is_stable():
            break
        e = err(m)
        if e < best_err:
            best, best_err = m, e
        a = m.a
    if best is None:
        return base
    return LinearModel(best, q, base.fs, base.u0, base.y0, 'off-plateau')
