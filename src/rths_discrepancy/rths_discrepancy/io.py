"""Input of the discrepancy workflow: CSV loading and validation of the column contract.

Columns (SI units):

* specimen: ``time`` [s], ``base_accel`` [m/s^2] (absolute acceleration of
  the DTM frame, input of eq. 46-47), ``rel_disp`` [m] (x_d2s), ``force`` [N]
  (force the damper exerts on its frame, ``c_d xd + k_d x = -m_d xdd_d``,
  eq. 45);
* actuator: ``time`` [s], ``command`` [m] (input), ``measured`` [m] (output).

Sampling must be uniform (any rate).  Every problem raises ``ValueError``
naming the file/column and the fix.
"""

import numpy as np

from rths_common import bagio
from rths_common.columns import read_columns
from rths_common.files import atomic_open
from rths_common.timebase import infer_rate, sampling_rate_hz
from rths_numerical.dtm import FRAME_MASS_KG

#: Required columns per scenario: (input, output channels...).
COLUMNS = {
    'specimen': ('time', 'base_accel', 'rel_disp', 'force'),
    'actuator': ('time', 'command', 'measured'),
}

#: Fewest samples the workflow accepts (train/held-out split into blocks).
MIN_SAMPLES = 512
#: Shortest record [s] (several periods of the DTM, f_n = 2.81 Hz, Table 4).
MIN_DURATION_S = 4.0


def validate(scenario: str, data: dict, source: str = 'data') -> dict:
    """Check ``data`` (column name -> array) against the contract; return float arrays.

    Raises ValueError for an unknown scenario, a missing column, unequal
    lengths, NaN/inf, non-increasing or non-uniform time, or a record too
    short to split into training and held-out parts.
    """
    if scenario not in COLUMNS:
        raise ValueError(f'unknown scenario {scenario!r}; use one of {", ".join(COLUMNS)}')
    need = COLUMNS[scenario]
    missing = [c for c in need if c not in data]
    if missing:
        raise ValueError(f'{source}: missing column(s) {", ".join(missing)} for scenario '
                         f'{scenario}; the columns must be {", ".join(need)}')
    out = {c: np.asarray(data[c], dtype=float).ravel() for c in need}
    n = out['time'].size
    for c in need:
        if out[c].size != n:
            raise ValueError(f'{source}: column {c} has {out[c].size} values, time has {n}')
        bad = ~np.isfinite(out[c])
        if bad.any():
            i = int(np.argmax(bad))
            raise ValueError(f'{source}: column {c} has {int(bad.sum())} NaN/inf value(s), first '
                             f'at row {i}; remove or interpolate them')
    t = out['time']
    if n < 3:
        raise ValueError(f'{source}: only {n} rows; need at least {MIN_SAMPLES}')
    infer_rate(t, source)                   # increasing and uniform, within the printing
    if n < MIN_SAMPLES or t[-1] - t[0] < MIN_DURATION_S:
        raise ValueError(f'{source}: record too short to split into training and held-out parts '
                         f'({n} samples, {t[-1] - t[0]:.3g} s); need >= {MIN_SAMPLES} samples and '
                         f'>= {MIN_DURATION_S:g} s')
    return out


def sample_rate(data: dict) -> float:
    """Return the sampling rate [Hz] of validated ``data`` (:mod:`rths_common.timebase`)."""
    return sampling_rate_hz(data['time'])


def load_csv(path, scenario: str) -> dict:
    """Read a CSV with a header row and return the validated columns of ``scenario``.

    Empty cells are read as NaN, for :func:`validate` to name them.
    """
    if scenario not in COLUMNS:
        raise ValueError(f'unknown scenario {scenario!r}; use one of {", ".join(COLUMNS)}')
    cols = read_columns(path, COLUMNS[scenario], keep_nan=True, min_rows=0)
    return validate(scenario, cols, source=str(path))


def read_bag(bag, scenario: str) -> dict:
    """Return the columns of ``scenario`` from an rths run bag (not yet validated).

    ``actuator``: ``time``, ``command`` and ``measured``: the plant as the loop sees it
    (the command of step k and the displacement measured at step k), as ``rths identify``
    reads it, so an identified plant.yaml is its nominal model and a delay in the
    bridge's command path (``command_delay_steps``) is the loop's ``time_delay``.
    ``specimen``: ``time``, ``base_accel``, ``rel_disp`` and ``force``
    (:func:`rths_common.bagio.read_specimen`; the frame mass defaults to Table 4's).
    """
    if scenario == 'actuator':
        t, command, measured = bagio.read_identification(bag, loop=True)
        return {'time': t, 'command': command, 'measured': measured}
    if scenario != 'specimen':
        raise ValueError(f"scenario {scenario!r}: use 'specimen' or 'actuator'")

    return bagio.read_specimen(bag, FRAME_MASS_KG)


def write_csv(path, data: dict, columns) -> None:
    """Write ``columns`` of ``data`` as CSV with a header row (atomic)."""
    arr = np.column_stack([np.asarray(data[c], float) for c in columns])
    with atomic_open(path) as handle:
        np.savetxt(handle, arr, delimiter=',', header=','.join(columns), comments='',
                   fmt='%.10g')
