"""Causal discrete-time filters applied sample by sample (the compensator's run-time core).

Every compensator of the seed (FIR compensator eq. 28, inverse compensation eq. 2,
model-based feed-forward eq. 4 discretised, NPZ-Ignore eq. 8, modified ZPETC eq. 12,
ZMETC eq. 14) is a causal rational filter

    G(z^-1) = (b0 + b1 z^-1 + ... + bn z^-n) / (a0 + a1 z^-1 + ... + am z^-m),

i.e. the difference equation  a0 y_k = sum_i b_i x_{k-i} - sum_{j>=1} a_j y_{k-j}.
:class:`MultiChannelFilter` evaluates it one sample at a time in direct form I
(:class:`CausalFilter` is its one-channel form).  The input and
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


class CausalFilter:
    """Causal rational filter ``G(z^-1) = B(z^-1)/A(z^-1)`` on one channel, one sample per step.

    ``taps`` are the numerator coefficients b0..bn, ``denominator`` a0..am (a0 != 0;
    ``(1.0,)`` gives a pure FIR).  :meth:`step` returns the output for one new input
    sample; :meth:`apply` filters a whole array from the current state and equals
    ``scipy.signal.lfilter(taps, denominator, x)`` to round-off when started from rest.
    It is a one-channel :class:`MultiChannelFilter` (one implementation of the recursion).
    """

    def __init__(self, taps, denominator=(1.0,)):
        self._filter = MultiChannelFilter(taps, denominator, n_channels=1)
        self.taps = self._filter.taps
        self.denominator = self._filter.denominator

    @property
    def is_fir(self) -> bool:
        """Return True if the denominator is 1 (finite impulse response)."""
        return self.denominator.size == 1

    def reset(self) -> None:
        """Return to rest (all past inputs and outputs zero)."""
        self._filter.reset()

    def step(self, x: float) -> float:
        """Feed input sample ``x_k`` and return output ``y_k``."""
        return float(self._filter.step((x,))[0])

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
        self._nb = self.taps.size
        self._na = self.denominator.size - 1
        self._a_rest = np.ascontiguousarray(self.denominator[1:])
        self._xbuf = np.zeros((2 * self._nb, self.n_channels))
        self._ybuf = np.zeros((2 * max(self._na, 1), self.n_channels))
        self._px = 0
        self._py = 0

    def reset(self) -> None:
        """Return all channels to rest."""
        self._xbuf[:] = 0.0
        self._ybuf[:] = 0.0
        self._px = 0
        self._py = 0

    def step(self, x) -> np.ndarray:
        """Feed one sample per channel and return one output per channel."""
        x = np.asarray(x, dtype=float)
        if x.shape != (self.n_channels,):
            raise ValueError(f'MultiChannelFilter.step expects shape ({self.n_channels},), '
                             f'got {x.shape}')
        nb = self._nb
        p = self._px - 1
        if p < 0:
            p = nb - 1
        self._px = p
        xb = self._xbuf
        xb[p] = x
        xb[p + nb] = x
        y = self.taps @ xb[p:p + nb]
        na = self._na
        if na:
            q = self._py
            yb = self._ybuf
            y = y - self._a_rest @ yb[q:q + na]
            q -= 1
            if q < 0:
                q = na - 1
            yb[q] = y
            yb[q + na] = y
            self._py = q
        return y

    def apply(self, x) -> np.ndarray:
        """Filter ``x`` of shape ``(n_samples, n_channels)`` sample by sample."""
        x = np.asarray(x, dtype=float)
        return np.array([self.step(row) for row in x]).reshape(x.shape)
