"""Causal discrete-time filters applied sample by sample (the compensator's run-time core).

Every compensator of the seed (FIR compensator eq. 28, inverse compensation eq. 2,
model-based feed-forward eq. 4 discretised, NPZ-Ignore eq. 8, modified ZPETC eq. 12,
ZMETC eq. 14) is a causal rational filter

    G(z^-1) = (b0 + b1 z^-1 + ... + bn z^-n) / (a0 + a1 z^-1 + ... + am z^-m),

i.e. the difference equation  a0 y_k = sum_i b_i x_{k-i} - sum_{j>=1} a_j y_{k-j}.
:class:`MultiChannelFilter` evaluates it one sample at a time in direct form I
(:class:`CausalFilter` is its one-channel form, in Python floats).  The input and
output histories live in *doubled ring buffers*: each new sample is written at position
``p`` and ``p + n``, so ``buf[p:p + n]`` is always the contiguous history
``x_k, x_{k-1}, ..., x_{k-n+1}`` and one ``numpy.dot`` per step evaluates the sum,
without copying or rolling arrays (a few microseconds for 400 taps in CPython).
"""

import numpy as np


def _as_coefficients(values, name: str) -> np.ndarray:
    arr = np.atleast_1d(np.asarray(values, dtype=float)).ravel()
    if arr.size == 0:
        raise ValueError(f'filter {name} is empty; give at least one coefficient')
    if not np.all(np.isfinite(arr)):
        raise ValueError(f'filter {name} holds non-finite values (nan/inf)')
    return arr


class History:
    """The last ``n`` samples of ``n_channels`` channels in a doubled ring buffer (module doc).

    :meth:`push` writes the newest sample at ``p`` and ``p + n``; :meth:`window` is then
    the contiguous view ``x_k, x_{k-1}, ..., x_{k-n+1}`` (one row per sample), no copy.
    """

    def __init__(self, n: int, n_channels: int | None = None):
        self.n = int(n)
        # n_channels None: one channel as scalars (a 1-D buffer)
        self.buf = np.zeros(2 * self.n if n_channels is None else (2 * self.n, int(n_channels)))
        self.p = 0

    def reset(self) -> None:
        """Forget every sample (all zero)."""
        self.buf[:] = 0.0
        self.p = 0

    def window(self) -> np.ndarray:
        """Return the last ``n`` samples, newest first (a view of the buffer)."""
        return self.buf[self.p:self.p + self.n]

    def push(self, x) -> np.ndarray:
        """Write the newest sample ``x`` (one value per channel); return :meth:`window`."""
        n, p = self.n, self.p - 1
        if p < 0:
            p = n - 1
        self.p = p
        buf = self.buf
        buf[p] = x
        buf[p + n] = x
        return buf[p:p + n]


#: Below this many coefficients numpy sums a dot product left to right, as plain Python
#: does (checked bit for bit by test_filters_params); from it on it sums in blocks.
_SEQUENTIAL_MAX = 15


def _numpy_sums_in_order(draws: int = 64) -> bool:
    """Return True if numpy sums a short dot product left to right here, as the short path does.

    Up to :data:`_SEQUENTIAL_MAX` terms.  Not on every machine: OpenBLAS picks its dot
    kernel by CPU, and on an AVX-512 AMD EPYC VM (2026-11-28) its sum of 5 terms differed
    from the left-to-right one by an ulp at a 5-tap filter's 9th step.  Checked on random
    terms over six decades, as a filter's.
    """
    rng = np.random.default_rng(0)
    for n in range(2, _SEQUENTIAL_MAX + 1):
        for _ in range(draws):
            c = rng.standard_normal(n) * 10.0 ** rng.uniform(-3, 3, n)
            h = rng.standard_normal(n) * 10.0 ** rng.uniform(-3, 3, n)
            total = 0.0
            for ci, hi in zip(c.tolist(), h.tolist(), strict=True):
                total += ci * hi
            if float(np.dot(c, h)) != total:
                return False
    return True


#: The short path is used only where it sums as numpy does (else numpy.dot at every size).
_SHORT_PATH = _numpy_sums_in_order()


class _Taps:
    """``sum_i c_i h_i`` over a newest-first history h, the arithmetic of ``c @ h``.

    Short (<= :data:`_SEQUENTIAL_MAX`, on a machine whose numpy sums that many terms in
    order: :data:`_SHORT_PATH`): Python floats summed left to right in a list (no numpy
    call per step).  Long: a doubled ring buffer and one ``numpy.dot`` (numpy's block
    order, the same as :class:`MultiChannelFilter`'s).
    """

    def __init__(self, coefficients: np.ndarray):
        self.c = np.ascontiguousarray(coefficients, dtype=float)
        self.n = int(self.c.size)
        self.short = self.n <= _SEQUENTIAL_MAX and _SHORT_PATH
        self.c_list = self.c.tolist()
        self.ring = History(self.n)      # the long path's history
        self.reset()

    def reset(self) -> None:
        self.hist = [0.0] * self.n       # the short path's history
        self.ring.reset()

    def _short_sum(self) -> float:
        total = 0.0
        for c, h in zip(self.c_list, self.hist, strict=True):
            total += c * h
        return total

    def _short_push(self, value: float) -> None:
        self.hist.insert(0, value)
        self.hist.pop()

    def push_sum(self, value: float) -> float:
        """Push ``value`` (newest first) and return the sum over the history."""
        if self.short:
            self._short_push(value)
            return self._short_sum()
        return float(np.dot(self.c, self.ring.push(value)))

    def sum_then_push(self, value_of) -> float:
        """Return ``value_of(sum over the history)`` after pushing it (the recursion)."""
        if self.short:
            out = value_of(self._short_sum())
            self._short_push(out)
            return out
        out = value_of(float(np.dot(self.c, self.ring.window())))
        self.ring.push(out)
        return out


class CausalFilter:
    """Causal rational filter ``G(z^-1) = B(z^-1)/A(z^-1)`` on one channel, one sample per step.

    ``taps`` are the numerator coefficients b0..bn, ``denominator`` a0..am (a0 != 0;
    ``(1.0,)`` gives a pure FIR).  :meth:`step` returns the output for one new input
    sample (Python floats in and out: the adaptive methods' per-step path); :meth:`apply`
    filters a whole array from the current state and equals
    ``scipy.signal.lfilter(taps, denominator, x)`` to round-off when started from rest.
    Its arithmetic is that of a one-channel :class:`MultiChannelFilter`, bit for bit
    (the same products summed in the same order; test_filters_params), at a fraction of
    the cost: no array per sample, short sums in Python floats.
    """

    def __init__(self, taps, denominator=(1.0,)):
        b = _as_coefficients(taps, 'taps')
        a = _as_coefficients(denominator, 'denominator')
        if a[0] == 0.0:
            raise ValueError('filter denominator a0 is 0; the leading coefficient must be '
                             'non-zero')
        self.taps = b / a[0]
        self.denominator = a / a[0]
        self._num = _Taps(self.taps)
        self._den = _Taps(self.denominator[1:]) if self.denominator.size > 1 else None

    @property
    def is_fir(self) -> bool:
        """Return True if the denominator is 1 (finite impulse response)."""
        return self.denominator.size == 1

    def reset(self) -> None:
        """Return to rest (all past inputs and outputs zero)."""
        self._num.reset()
        if self._den is not None:
            self._den.reset()

    def step(self, x: float) -> float:
        """Feed input sample ``x_k`` and return output ``y_k``."""
        y = self._num.push_sum(float(x))
        if self._den is None:
            return y
        return self._den.sum_then_push(y.__sub__)

    def apply(self, x) -> np.ndarray:
        """Filter the 1-D array ``x`` sample by sample from the current state; return outputs."""
        x = np.asarray(x, dtype=float).ravel()
        step = self.step
        return np.fromiter((step(v) for v in x), dtype=float, count=x.size)


class MultiChannelFilter:
    """The same causal rational filter applied independently to ``n_channels`` channels.

    :meth:`step` takes one sample per channel (shape ``(n_channels,)``) and returns the
    outputs; one matrix-vector product per step serves all channels.
    """

    def __init__(self, taps, denominator=(1.0,), n_channels: int = 1):
        if int(n_channels) < 1:
            raise ValueError(f'n_channels must be >= 1, got {n_channels}')
        b = _as_coefficients(taps, 'taps')
        a = _as_coefficients(denominator, 'denominator')
        if a[0] == 0.0:
            raise ValueError('filter denominator a0 is 0; the leading coefficient must be '
                             'non-zero')
        self.taps = b / a[0]
        self.denominator = a / a[0]
        self.n_channels = int(n_channels)
        self._shape = (self.n_channels,)
        self._nb = self.taps.size
        self._na = self.denominator.size - 1
        self._a_rest = np.ascontiguousarray(self.denominator[1:])
        self._x = History(self._nb, self.n_channels)
        self._y = History(max(self._na, 1), self.n_channels)

    def reset(self) -> None:
        """Return all channels to rest."""
        self._x.reset()
        self._y.reset()

    def step(self, x) -> np.ndarray:
        """Feed one sample per channel and return one output per channel."""
        x = np.asarray(x, dtype=float)
        if x.shape != self._shape:
            raise ValueError(f'MultiChannelFilter.step expects shape ({self.n_channels},), '
                             f'got {x.shape}')
        y = self.taps @ self._x.push(x)
        if self._na:
            y -= self._a_rest @ self._y.window()      # y is new: y - (...) without a copy
            self._y.push(y)
        return y

    def apply(self, x) -> np.ndarray:
        """Filter ``x`` of shape ``(n_samples, n_channels)`` sample by sample."""
        x = np.asarray(x, dtype=float)
        return np.array([self.step(row) for row in x]).reshape(x.shape)


class CoupledFir:
    """An N x N matrix of FIR filters: command i = sum over l of ``taps[i, l]`` on target l.

    The coupled (MIMO) compensator of a multi-actuator rig (the maRTHS benchmark's ``mimo``
    controller, ``rths_compensator.multichannel.design_coupled_fir``): each actuator's
    command answers every actuator's target, so the specimen's coupling between them can
    be cancelled.
    The same :class:`History` as :class:`MultiChannelFilter`; one matrix-vector product
    (N x N n) per step.
    """

    def __init__(self, taps):
        """Use ``taps`` of shape (N, N, n): ``taps[i, l, j]`` is the lag-j tap l -> i."""
        t = np.asarray(taps, dtype=float)
        if t.ndim != 3 or t.shape[0] != t.shape[1] or t.shape[2] < 1:
            raise ValueError(f'coupled FIR taps must have the shape (N, N, n), got {t.shape}')
        if not np.all(np.isfinite(t)):
            raise ValueError('coupled FIR taps hold non-finite values (nan/inf)')
        self.taps = t
        self.n_channels, _, self._nb = t.shape
        # W[i, j N + l] = taps[i, l, j]: the history rows x_k, x_k-1, ... flattened
        self._w = np.ascontiguousarray(t.transpose(0, 2, 1).reshape(self.n_channels, -1))
        self._x = History(self._nb, self.n_channels)

    @classmethod
    def from_flat(cls, values, n_channels: int, where: str = 'coupled_taps') -> 'CoupledFir':
        """Build it from N^2 n values (N = ``n_channels``): entry ``(i N + l) n + j``."""
        v = np.asarray(values, dtype=float).ravel()
        n = int(n_channels)
        if n < 1 or v.size == 0 or v.size % (n * n):
            raise ValueError(f'{where}: {v.size} values are not N x N x n taps for N = {n} '
                             f'actuator channels; give N * N * n values (entry (i N + l) n + j '
                             'maps target l to command i at lag j)')
        return cls(v.reshape(n, n, -1))

    def reset(self) -> None:
        """Return to rest."""
        self._x.reset()

    def step(self, x) -> np.ndarray:
        """Feed one target per channel and return one command per channel."""
        x = np.asarray(x, dtype=float)
        if x.shape != (self.n_channels,):
            raise ValueError(f'CoupledFir.step expects shape ({self.n_channels},), got {x.shape}')
        return self._w @ self._x.push(x).reshape(-1)
