"""Writing the CSV time series of the compensator commands (reading: rths_common.columns)."""

import os

import numpy as np

from rths_common.files import atomic_open


def write_csv_columns(path, columns: dict) -> str:
    """Atomically write equal-length ``columns`` (name -> array) as CSV with a header."""
    path = os.fspath(path)
    names = list(columns)
    data = np.column_stack([np.asarray(columns[n], dtype=float) for n in names])
    with atomic_open(path) as handle:
        np.savetxt(handle, data, delimiter=',', header=','.join(names), comments='',
                   fmt='%.10g')
    return path
