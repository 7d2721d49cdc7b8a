"""The ideal specimen (``backend: ideal``): a perfect actuator on a linear spring, n channels.

The measured displacement is the command itself and the force the spring's::

    displacement_k = u_k,     force_k = K u_k          (K: n x n, ``stiffness_n_m``)

No dynamics, no noise: what a protocol, a multi-DOF mapping or a loop is
checked against (the site's bit-for-bit comparisons, ``rths bench site``).
``stiffness_n_m`` is one value per channel (a diagonal K) or n x n values
row by row.
"""

import numpy as np

from .backend import Backend

#: Ideal-backend parameters: key -> (type, default, meaning with unit).
IDEAL_PARAMS = {
    'n_channels': (int, 1, '[-] number of actuators'),
    'stiffness_n_m': (list, [0.0], '[N/m] spring stiffness: one value per channel (diagonal) '
                      'or n x n values row by row'),
}
#: Ranges of :data:`IDEAL_PARAMS` (inclusive).
IDEAL_RANGES = {'n_channels': (1, 64)}


def stiffness_matrix(value, n: int) -> np.ndarray:
    """Return the n x n stiffness [N/m] of ``stiffness_n_m`` (ValueError names the fix)."""
    k = np.atleast_1d(np.asarray(value, dtype=float)).ravel()
    if k.size == n:
        k = np.diag(k)
    elif k.size == n * n:
        k = k.reshape(n, n)
    else:
        raise ValueError(f"parameter 'stiffness_n_m' has {k.size} value(s); give {n} (one per "
                         f'channel) or {n * n} (an n x n matrix row by row) for n_channels {n}')
    if not np.all(np.isfinite(k)):
        raise ValueError("parameter 'stiffness_n_m' holds nan/inf; give finite N/m values")
    return k


class IdealBackend(Backend):
    """Perfect actuator, linear spring specimen (module docstring)."""

    summary = 'ideal specimen: a perfect actuator on a linear spring (checks and benchmarks)'
    params = IDEAL_PARAMS
    ranges = IDEAL_RANGES
    in_process = True

    def _configure(self, params: dict):
        n = params.get('n_channels', 1)
        if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= 64:
            raise ValueError(f"parameter 'n_channels' = {n!r} must be an integer in [1, 64]")
        self.n_channels = n
        self.stiffness = stiffness_matrix(params.get('stiffness_n_m', [0.0] * n), n)
        self._last = None

    def _activate(self):
        self._last = None

    def _deactivate(self):
        """Nothing to stop."""

    def _write(self, command):
        self._last = command.copy()

    def _read(self):
        if self._last is None:
            raise RuntimeError('read() before the first write()')
        return self._last.copy(), self.stiffness @ self._last
