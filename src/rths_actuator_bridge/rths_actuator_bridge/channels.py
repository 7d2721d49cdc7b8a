"""The simulated plant's output channels and its ZOH discretisation.

Shared by :mod:`.simulated` (the plant) and the specimens it can carry
(:mod:`.stroke_specimen`), which import them from here, not from each other.
"""

import numpy as np

#: Specimen-scenario channels exposed by :meth:`SimulatedPlant.channels`.
CHANNELS = ('table_disp', 'table_vel', 'table_accel', 'rel_disp', 'rel_vel', 'force')


def zoh(a: np.ndarray, b: np.ndarray, dt: float):
    """Exact ZOH discretisation of ``x' = A x + B u`` over ``dt`` (augmented expm)."""
    n, m = b.shape
    big = np.zeros((n + m, n + m))
    big[:n, :n] = a
    big[:n, n:] = b
    # lazy: start-up cost: scipy.linalg (~0.4 s) for every `rths` command (the CLI lists this)
    from scipy.linalg import expm

    e = expm(big * dt)
    return e[:n, :n], e[:n, n:]
