"""A linear state-space specimen from a file: stroke and velocity in, force out.

The file (YAML) describes a lab's own linear specimen between the floor and the ground
(a bearing, a damper, a fitted model of a device)::

    A: [[0, 1], [-400, -4]]      # state matrix (n x n) [1/s, ...]
    B: [[0, 0], [1, 0]]          # inputs [stroke x [m], velocity v [m/s]] (n x 2)
    C: [[2.0e5, 0]]              # force output (1 x n) [N per state]
    D: [[0, 0]]                  # direct term (1 x 2) [N/m, N s/m]

``f = C q + D [x, v]``, ``q' = A q + B [x, v]``; A must be stable (every eigenvalue's
real part negative) and every entry finite.  It is integrated exactly over each
sub-step with the inputs linear in time (first-order hold, scipy expm).
"""

import numpy as np
from scipy.linalg import expm
import yaml


def load_state_space(path) -> dict:
    """Return ``{'A', 'B', 'C', 'D'}`` of a state-space specimen file (ValueError naming it)."""
    try:
        with open(path) as fh:
            data = yaml.safe_load(fh)
    except OSError as err:
        raise ValueError(f'statespace_file {path}: {err.strerror}; give the path of a YAML file '
                         'with A, B, C, D') from None
    if not isinstance(data, dict):
        raise ValueError(f'statespace_file {path}: expected a mapping with A, B, C, D')
    mats = {}
    for key in ('A', 'B', 'C', 'D'):
        try:
            mats[key] = np.atleast_2d(np.asarray(data[key], dtype=float))
        except KeyError:
            raise ValueError(f'statespace_file {path}: missing {key}') from None
        except (TypeError, ValueError):
            raise ValueError(f'statespace_file {path}: {key} must be a matrix of numbers') \
                from None
        if not np.all(np.isfinite(mats[key])):
            raise ValueError(f'statespace_file {path}: {key} holds nan/inf')
    n = mats['A'].shape[0]
    want = {'A': (n, n), 'B': (n, 2), 'C': (1, n), 'D': (1, 2)}
    for key, shape in want.items():
        if mats[key].shape != shape:
            raise ValueError(f'statespace_file {path}: {key} is {mats[key].shape}, expected '
                             f'{shape} (inputs: stroke and velocity; output: the force)')
    worst = float(np.max(np.linalg.eigvals(mats['A']).real))
    if not worst < 0:
        raise ValueError(f'statespace_file {path}: A is not stable (an eigenvalue has real '
                         f'part {worst:g} >= 0); a specimen must come to rest')
    return mats


class StateSpaceSpecimen:
    """A device (``reset``, ``advance``, ``force``) from :func:`load_state_space`'s matrices."""

    def __init__(self, mats: dict):
        """Keep the matrices; the exact sub-step matrices are made for each new step length."""
        self.a, self.b = mats['A'], mats['B']
        self.c, self.d = mats['C'][0], mats['D'][0]
        self.q = np.zeros(self.a.shape[0])
        self.u = np.zeros(2)
        self._h = None

    def reset(self):
        """Return to rest."""
        self.q[:] = 0.0
        self.u[:] = 0.0

    def _matrices(self, h: float):
        """Return the first-order-hold step matrices for inputs linear over ``h`` seconds."""
        n = self.a.shape[0]
        big = np.zeros((n + 4, n + 4))
        big[:n, :n] = self.a * h
        big[:n, n:n + 2] = self.b * h
        big[n:n + 2, n + 2:] = np.eye(2)
        e = expm(big)
        phi, g1, g2 = e[:n, :n], e[:n, n:n + 2], e[:n, n + 2:]
        self._h, self._phi, self._g0, self._g1 = h, phi, g1 - g2, g2
        return self._phi, self._g0, self._g1

    def advance(self, x0, v0, x1, v1, h):
        """Advance the states over ``h`` seconds with stroke and velocity linear in between."""
        phi, g0, g1 = (self._phi, self._g0, self._g1) if h == self._h else self._matrices(h)
        u0, u1 = np.array([x0, v0]), np.array([x1, v1])
        self.q = phi @ self.q + g0 @ u0 + g1 @ u1
        self.u = u1

    def force(self):
        """Return the force [N] on the table."""
        return float(self.c @ self.q + self.d @ self.u)
