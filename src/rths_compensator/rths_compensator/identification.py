"""ARX identification and model-order selection of the plant (seed section 4.3.1.2).

ARX model, eq. 26 (d = dead time in samples)::

    y(t) + a1 y(t-1) + ... + a_na y(t-na) = b1 u(t-d) + ... + b_nb u(t-d-nb+1) + e(t)

with transfer function eq. 27, ``T(z^-1) = z^-d (b1 + ... + b_nb z^-(nb-1)) / A(z^-1)``.
Parameters are fitted by linear least squares on the regression
``y(t) = phi(t)^T theta``, ``phi(t) = [-y(t-1..t-na), u(t-d..t-d-nb+1)]``.

Fast grid (na, nb = 1..29, several d): one regression matrix with the MAXIMUM lags is
built per record, and only its Gram matrix ``G = Phi^T Phi``, ``r = Phi^T y`` and
``y^T y`` are kept.  Every nested model is a sub-block: ``theta = G[I, I]^-1 r[I]``
(Cholesky of a <= 58x58 matrix), and its one-step-ahead prediction error on ANY record
follows from that record's Gram data without touching the samples:
``N * MSE = y^T y - 2 theta^T r_v[I] + theta^T G_v[I, I] theta``.
(This is the prediction-error loss MATLAB's arxstruc/selstruc use; ``error='prediction'``.)
By default the validation error is the SIMULATION (output) error of each model, computed
with one vectorised ``lfilter`` over all validation records per model: at 1024 Hz the
one-step predictor error is dominated by measurement noise and selects over-fitted
models with many spurious zeros, whereas the compensators need the simulated response.

Selection criteria over each validation record (N samples, dim = na + nb):
MSE eq. 37, FIT eq. 38 ``sqrt(MSE)/std(y)``, AIC eq. 39 ``ln(MSE) + 2 dim/N``,
BIC eq. 40 ``ln(MSE) + ln(N) dim/N``.  Per criterion the winner of each record is
counted (the histogram of Figure 5) and the most frequent model is selected; the seed
uses BIC.

Zero factorisation, eq. 7: ``B*(z^-1) = B+*(z^-1) B-*(z^-1)``, B+* (monic) holding the
zeros strictly inside the unit circle and B-* (carrying the gain b1) the others.
"""

import dataclasses
import os
import warnings

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy import linalg, signal
import yaml

from rths_common import yamlfile
from rths_common.files import atomic_open
from rths_common.timebase import sampling_rate_hz

from .plant_effects import fold_effects, split_effects

CRITERIA = ('mse', 'fit', 'aic', 'bic')


@dataclasses.dataclass
class ArxModel:
    """ARX plant model (eq. 26-27): ``a = [1, a1..a_na]``, ``b = [b1..b_nb]``, dead time d."""

    a: np.ndarray
    b: np.ndarray
    d: int = 0
    fs_hz: float = 1024.0
    #: non-linear loads on the servo loop ``{effect: value}`` of an updated model (not in
    #: the coefficients: the compensator applies them as a feed-forward, .feedforward)
    loads: dict = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        self.a = np.atleast_1d(np.asarray(self.a, dtype=float)).ravel()
        self.b = np.atleast_1d(np.asarray(self.b, dtype=float)).ravel()
        self.d = int(self.d)
        self.fs_hz = float(self.fs_hz)
        if self.a.size == 0 or self.a[0] == 0:
            raise ValueError('ARX field a must start with a non-zero a0 (normally 1)')
        if self.b.size == 0:
            raise ValueError('ARX field b is empty')
        if self.d < 0:
            raise ValueError(f'ARX dead time d must be >= 0, got {self.d}')
        if not (np.all(np.isfinite(self.a)) and np.all(np.isfinite(self.b))):
            raise ValueError('ARX coefficients hold nan/inf')
        if self.a[0] != 1.0:
            self.b = self.b / self.a[0]
            self.a = self.a / self.a[0]

    @property
    def na(self) -> int:
        """Return the number of poles (denominator order)."""
        return self.a.size - 1

    @property
    def nb(self) -> int:
        """Return the number of numerator coefficients."""
        return self.b.size

    @property
    def num(self) -> np.ndarray:
        """Numerator in powers of z^-1 including the dead time: ``[0]*d + b``."""
        return np.concatenate([np.zeros(self.d), self.b])

    def simulate(self, u) -> np.ndarray:
        """Noise-free response ``y`` of the model to the input ``u`` from rest."""
        return signal.lfilter(self.num, self.a, np.asarray(u, dtype=float))

    def is_stable(self) -> bool:
        """Return True if every pole lies strictly inside the unit circle."""
        return self.na == 0 or bool(np.max(np.abs(np.roots(self.a))) < 1.0)

    def dc_gain(self) -> float:
        """Steady-state gain ``B(1)/A(1)``."""
        return float(np.sum(self.b) / np.sum(self.a))

    def to_dict(self) -> dict:
        """Plain-Python dict (the body of plant.yaml without ``selection``)."""
        return {'kind': 'arx', 'fs_hz': self.fs_hz, 'na': self.na, 'nb': self.nb, 'd': self.d,
                'a': [float(v) for v in self.a], 'b': [float(v) for v in self.b]}

    @classmethod
    def from_dict(cls, data: dict, where: str = 'plant') -> 'ArxModel':
        """Build from :meth:`to_dict` output; ValueError names the missing/bad field.

        An ``effects`` mapping (an ``updated_model.yaml`` of ``rths discrepancy``) is
        folded into the coefficients by :func:`.plant_effects.fold_effects`; its non-linear
        loads on the servo loop are kept in ``loads`` (the compensator's feed-forward); any
        other effect is refused.
        """
        if not isinstance(data, dict):
            raise ValueError(f'{where}: expected a mapping with kind, fs_hz, a, b, d')
        if data.get('kind') == 'state_space':
            raise ValueError(f"{where}: an N x N plant of {data.get('n_channels', '?')} actuators "
                             '(rths identify --channels N); this takes one actuator\'s ARX '
                             'plant (rths identify without --channels)')
        if data.get('kind', 'arx') != 'arx':
            raise ValueError(f"{where}: field kind is {data.get('kind')!r}; only 'arx' is known")
        for field in ('fs_hz', 'a', 'b'):
            if field not in data:
                raise ValueError(f'{where}: field {field} missing; re-run rths identify')
        fs_hz = data['fs_hz']
        if not _is_real(fs_hz) or not (np.isfinite(fs_hz) and fs_hz > 0):
            raise ValueError(f'{where}: field fs_hz = {fs_hz!r}; give the sampling rate in Hz, '
                             'a finite number > 0')
        for field in ('a', 'b'):
            value = data[field]
            if not (_is_real(value) or (isinstance(value, list) and value
                                        and all(_is_real(v) for v in value))):
                raise ValueError(f'{where}: field {field} = {str(value)[:60]}; give a '
                                 'non-empty list of numbers')
        for field in ('d', 'na', 'nb'):
            value = data.get(field, 0)
            if not (_is_real(value) and float(value).is_integer()):
                raise ValueError(f'{where}: field {field} = {value!r}; give a whole number >= 0')
        if not 0 <= data.get('d', 0) <= fs_hz:   # a dead time of samples: at most 1 s
            raise ValueError(f"{where}: field d = {data.get('d', 0)!r}; give the dead time in "
                             f'samples, 0 to {fs_hz:g} (1 s at fs_hz)')
        model = cls(a=data['a'], b=data['b'], d=data.get('d', 0), fs_hz=fs_hz)
        for field, value in (('na', model.na), ('nb', model.nb)):
            if field in data and int(data[field]) != value:
                raise ValueError(f'{where}: field {field} = {data[field]} does not match the '
                                 f'length of the coefficient list ({value})')
        if data.get('effects'):
            foldable, loads = split_effects(data['effects'], where)
            a, b, d = fold_effects(model.a, model.b, model.d, model.fs_hz, foldable, where)
            model = cls(a=a, b=b, d=d, fs_hz=model.fs_hz, loads=loads)
        return model


def _is_real(value) -> bool:
    """Return True for a plain number as YAML gives it (an int or float; no bool, no text)."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)


def save_plant(path, model: ArxModel, selection_info: dict = None) -> str:
    """Atomically write ``plant.yaml``: ``{kind: arx, fs_hz, na, nb, d, a, b, selection}``."""
    path = os.fspath(path)
    doc = model.to_dict()
    doc['selection'] = _plain(selection_info or {})
    text = yaml.safe_dump(doc, default_flow_style=None, sort_keys=False, width=100)
    with atomic_open(path) as handle:
        handle.write(text)
    return path


def load_plant(path) -> ArxModel:
    """Read ``plant.yaml`` written by :func:`save_plant`."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise OSError(f"{path}: plant file not found; create it with 'rths identify'")
    try:
        return ArxModel.from_dict(yamlfile.load(path), where=path)
    except ValueError as err:
        if path in str(err):
            raise
        raise ValueError(f'{path}: {err}') from None


def _plain(value):
    """Convert numpy containers/scalars to plain Python for YAML."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return [_plain(v) for v in value.tolist()]
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.floating,)):
        return float(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value


def factor_zeros(b, tol: float = 1.0):
    """Split ``B*(z^-1)`` into ``(b_plus, b_minus)`` with ``B* = B+* B-*`` (eq. 7).

    ``b = [b1, b2, ...]`` in powers of z^-1; its zeros (in z) are ``np.roots(b)``.
    ``b_plus`` is monic and holds the zeros with modulus < ``tol`` (stable);
    ``b_minus`` holds the others and the leading gain ``b1``.  Leading zeros of ``b``
    (dead time) are not zeros of B*: strip them first.
    """
    b = np.atleast_1d(np.asarray(b, dtype=float)).ravel()
    if b.size == 0 or b[0] == 0:
        raise ValueError('factor_zeros: b must be non-empty with b[0] != 0 (strip dead time)')
    zeros = np.roots(b)
    stable = zeros[np.abs(zeros) < tol]
    unstable = zeros[np.abs(zeros) >= tol]
    b_plus = np.real(np.poly(stable)) if stable.size else np.array([1.0])
    b_minus = b[0] * (np.real(np.poly(unstable)) if unstable.size else np.array([1.0]))
    return np.atleast_1d(b_plus), np.atleast_1d(b_minus)


# --------------------------------------------------------------------------- regression


def _regression(u, y, na_max, nb_max, d_max):
    """Regression matrix with maximum lags: columns -y(t-1..t-na_max), u(t..t-d_max-nb_max+1).

    Returns (Phi, target); the u block has ``d_max + nb_max`` columns (lag 0 first), so the
    columns of the model (na, nb, d) are ``range(na)`` and ``na_max + d + range(nb)``.
    """
    u = np.asarray(u, dtype=float).ravel()
    y = np.asarray(y, dtype=float).ravel()
    nu = d_max + nb_max
    t0 = max(na_max, nu - 1)
    n = y.size
    if n - t0 < 2 * (na_max + nu):
        raise ValueError(f'record of {n} samples too short for lags na={na_max}, '
                         f'nb+d={nu}; use longer records or smaller orders')
    ywin = sliding_window_view(y, na_max + 1)          # row j: y[j..j+na_max]
    uwin = sliding_window_view(u, nu)                 # row j: u[j..j+nu-1]
    rows = np.arange(t0, n)
    phi_y = -ywin[rows - na_max, :na_max][:, ::-1]     # y(t-1), ..., y(t-na_max)
    phi_u = uwin[rows - nu + 1][:, ::-1]              # u(t), u(t-1), ...
    return np.hstack([phi_y, phi_u]), y[rows]


@dataclasses.dataclass
class _Gram:
    g: np.ndarray
    r: np.ndarray
    yy: float
    n: int
    var_y: float


def _gram(u, y, na_max, nb_max, d_max) -> _Gram:
    phi, target = _regression(u, y, na_max, nb_max, d_max)
    return _Gram(phi.T @ phi, phi.T @ target, float(target @ target), target.size,
                 float(np.var(target)))


def _solve_scaled(g, r, idx, scale, ridge):
    """Solve the normal equations of the sub-model ``idx`` (column-scaled, tiny ridge)."""
    gs = g[np.ix_(idx, idx)] / np.outer(scale[idx], scale[idx])
    gs[np.diag_indices_from(gs)] += ridge
    try:
        with warnings.catch_warnings():
            warnings.simplefilter('ignore', linalg.LinAlgWarning)
            return linalg.solve(gs, r[idx] / scale[idx], assume_a='pos') / scale[idx]
    except (linalg.LinAlgError, ValueError):
        return np.full(idx.size, np.nan)


def fit_arx(records, na: int, nb: int, d: int = 0, fs_hz: float = 1024.0,
            ridge: float = 0.0) -> ArxModel:
    """Least-squares ARX fit (eq. 26) of one order on records ``[(u, y), ...]``."""
    grams = [_gram(u, y, na, nb, d) for u, y in records]
    g = sum(gr.g for gr in grams)
    r = sum(gr.r for gr in grams)
    idx = np.r_[np.arange(na), na + d + np.arange(nb)]
    scale = np.sqrt(np.diag(g))
    scale[scale == 0] = 1.0
    theta = _solve_scaled(g, r, idx, scale, ridge)
    return ArxModel(a=np.r_[1.0, theta[:na]], b=theta[na:], d=d, fs_hz=fs_hz)


def arx_grid(train, validation, na_range=range(1, 30), nb_range=range(1, 30), d_range=(0,),
             fs_hz: float = 1024.0, error: str = 'simulation', ridge: float = 0.0,
             progress=None, warmup=None) -> dict:
    """Fit every ARX order of the grid on ``train`` and score it on each validation record.

    ``train`` and ``validation`` are lists of ``(u, y)`` arrays.  ``error`` is
    'simulation' (output error of the noise-free model response, default) or
    'prediction' (one-step-ahead, from Gram matrices only; very fast, but at 1024 Hz it
    is dominated by measurement noise and favours over-parameterised models).
    ``ridge`` is a relative Tikhonov term on the column-scaled normal equations that
    keeps the band-limited (rank-deficient) lag regressions solvable.  ``warmup`` (simulation
    error only; one int per validation record, or one for all) is the number of leading
    samples of a validation record that are simulated but not scored: where the validation
    part continues a record, the input before it brings the model to the state the system
    was in (from rest, a lightly damped model's start-up transient would be scored as its
    error and decide the orders).  Returns a dict with
    ``orders`` (K x 3 array of na, nb, d), ``thetas`` (list), ``scores`` (criterion ->
    V x K array, lower is better; nan/inf for failed models), ``winners`` (criterion ->
    index per record), ``histogram`` (criterion -> {(na, nb, d): count}) and ``best``
    (criterion -> index of the most frequent winner).
    """
    if error not in ('prediction', 'simulation'):
        raise ValueError(f"error must be 'prediction' or 'simulation', got {error!r}")
    na_range, nb_range, d_range = list(na_range), list(nb_range), list(d_range)
    na_max, nb_max, d_max = max(na_range), max(nb_range), max(d_range)
    if min(na_range) < 0 or min(nb_range) < 1 or min(d_range) < 0:
        raise ValueError('ARX grid needs na >= 0, nb >= 1, d >= 0')
    g_train = [_gram(u, y, na_max, nb_max, d_max) for u, y in train]
    g = sum(gr.g for gr in g_train)
    r = sum(gr.r for gr in g_train)
    scale = np.sqrt(np.diag(g))
    scale[scale == 0] = 1.0
    if error == 'prediction':
        g_val = [_gram(u, y, na_max, nb_max, d_max) for u, y in validation]
        gv = np.stack([gr.g for gr in g_val])
        rv = np.stack([gr.r for gr in g_val])
        yyv = np.array([gr.yy for gr in g_val])
        nv = np.array([gr.n for gr in g_val], dtype=float)
        var_v = np.array([gr.var_y for gr in g_val])
    else:
        u_val = [np.asarray(u, dtype=float) for u, _ in validation]
        y_val = [np.asarray(y, dtype=float) for _, y in validation]
        warm = ([0] * len(y_val) if warmup is None else
                [int(warmup)] * len(y_val) if np.isscalar(warmup) else [int(w) for w in warmup])
        if len(warm) != len(y_val) or any(not 0 <= w < y.size for w, y in
                                          zip(warm, y_val, strict=True)):
            raise ValueError('warmup: one count per validation record, each below its length')
        nv = np.array([y.size - w for y, w in zip(y_val, warm, strict=True)], dtype=float)
        var_v = np.array([np.var(y[w:]) for y, w in zip(y_val, warm, strict=True)])
        same_length = len(set(y.size for y in y_val)) == 1 and len(set(warm)) == 1
        w0 = warm[0]
        if same_length:
            u_mat, y_mat = np.stack(u_val), np.stack(y_val)
    orders, thetas, mse_rows = [], [], []
    total = len(na_range) * len(nb_range) * len(d_range)
    for d in d_range:
        for na in na_range:
            for nb in nb_range:
                idx = np.r_[np.arange(na), na_max + d + np.arange(nb)]
                theta = _solve_scaled(g, r, idx, scale, ridge)
                if error == 'prediction':
                    quad = np.einsum('vij,i,j->v', gv[:, idx[:, None], idx[None, :]], theta, theta)
                    mse = (yyv - 2 * rv[:, idx] @ theta + quad) / nv
                    mse = np.maximum(mse, np.finfo(float).tiny)
                else:
                    a = np.r_[1.0, theta[:na]]
                    num = np.r_[np.zeros(d), theta[na:]]
                    with np.errstate(all='ignore'):
                        if same_length:
                            e = y_mat - signal.lfilter(num, a, u_mat, axis=-1)
                            mse = np.mean(e[:, w0:] ** 2, axis=-1)
                        else:
                            mse = np.array([np.mean((y - signal.lfilter(num, a, u))[w:] ** 2)
                                            for u, y, w in zip(u_val, y_val, warm,
                                                               strict=True)])
                    mse = np.where(np.isfinite(mse), mse, np.inf)
                orders.append((na, nb, d))
                thetas.append(theta)
                mse_rows.append(mse)
                if progress is not None and len(orders) % 100 == 0:
                    progress(len(orders), total)
    mse = np.array(mse_rows).T                                  # V x K
    orders = np.array(orders)
    dim = (orders[:, 0] + orders[:, 1])[None, :]
    n = nv[:, None]
    with np.errstate(divide='ignore', invalid='ignore'):
        scores = {
            'mse': mse,
            'fit': np.sqrt(mse) / np.sqrt(var_v)[:, None],
            'aic': np.log(mse) + 2.0 * dim / n,
            'bic': np.log(mse) + np.log(n) * dim / n,
        }
    winners, histogram, best = {}, {}, {}
    for crit, s in scores.items():
        s = np.where(np.isfinite(s), s, np.inf)
        win = np.argmin(s, axis=1)
        counts = np.bincount(win, minlength=len(orders))
        winners[crit] = win
        histogram[crit] = {tuple(int(v) for v in orders[k]): int(counts[k])
                           for k in np.flatnonzero(counts)}
        best[crit] = int(np.argmax(counts))
    return {'orders': orders, 'thetas': thetas, 'scores': scores, 'winners': winners,
            'histogram': histogram, 'best': best, 'fs_hz': fs_hz, 'error': error}


def model_from_grid(grid: dict, criterion: str = 'bic') -> ArxModel:
    """Return the ArxModel most often selected by ``criterion`` in an :func:`arx_grid` result."""
    if criterion not in CRITERIA:
        raise ValueError(f'criterion {criterion!r} unknown; use one of {", ".join(CRITERIA)}')
    k = grid['best'][criterion]
    na, nb, d = (int(v) for v in grid['orders'][k])
    theta = grid['thetas'][k]
    return ArxModel(a=np.r_[1.0, theta[:na]], b=theta[na:], d=d, fs_hz=grid['fs_hz'])


def selection_summary(grid: dict, criterion: str = 'bic', top: int = 5) -> dict:
    """Plain dict for plant.yaml: criterion, orders, winner counts per criterion."""
    out = {'criterion': criterion, 'error': grid['error'],
           'n_models': int(len(grid['orders'])),
           'n_validation_records': int(len(grid['winners'][criterion]))}
    for crit in CRITERIA:
        k = grid['best'][crit]
        hist = sorted(grid['histogram'][crit].items(), key=lambda kv: -kv[1])[:top]
        out[crit] = {'na': int(grid['orders'][k][0]), 'nb': int(grid['orders'][k][1]),
                     'd': int(grid['orders'][k][2]),
                     'top': [f'na={o[0]} nb={o[1]} d={o[2]}: {c}' for o, c in hist]}
    return out


def split_records(time, command, measured, record_s: float = 10.0):
    """Cut one long (command, measured) run into consecutive records of ``record_s``."""
    t = np.asarray(time, dtype=float)
    n = int(round(record_s * sampling_rate_hz(t)))
    k = len(t) // n
    if k < 2:
        raise ValueError(f'run of {t[-1] - t[0]:.1f} s gives fewer than 2 records of '
                         f'{record_s} s; record longer or use a shorter --record-s')
    u = np.asarray(command, dtype=float)[:k * n].reshape(k, n)
    y = np.asarray(measured, dtype=float)[:k * n].reshape(k, n)
    return [(u[i], y[i]) for i in range(k)]


def identify(records_train, records_val, fs_hz: float, na_max: int = 29, nb_max: int = 29,
             d_max: int = 0, criterion: str = 'bic', error: str = 'simulation',
             progress=None):
    """Grid-identify and select an ARX plant; return ``(model, selection_info, grid)``."""
    grid = arx_grid(records_train, records_val, range(1, na_max + 1), range(1, nb_max + 1),
                    range(0, d_max + 1), fs_hz=fs_hz, error=error, progress=progress)
    model = model_from_grid(grid, criterion)
    return model, selection_summary(grid, criterion), grid
