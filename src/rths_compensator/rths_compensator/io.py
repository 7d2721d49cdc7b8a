"""Reading and writing the CSV time series of the compensator commands."""

import os

import numpy as np

from rths_common.files import atomic_open


def read_csv_columns(path, columns):
    """Read the named numeric ``columns`` of a CSV file with a header row; return a dict.

    Raises OSError if the file is missing and ValueError naming the missing column.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise OSError(f'{path}: CSV file not found')
    with open(path, encoding='utf-8') as handle:
        header = handle.readline().strip()
    names = [h.strip() for h in header.split(',')]
    missing = [c for c in columns if c not in names]
    if missing:
        raise ValueError(f'{path}: column(s) {", ".join(missing)} missing (header has '
                         f'{", ".join(names)}); the CSV needs columns {", ".join(columns)}')
    try:
        data = np.loadtxt(path, delimiter=',', skiprows=1, ndmin=2,
                          usecols=[names.index(c) for c in columns])
    except ValueError as err:
        raise ValueError(f'{path}: non-numeric data ({err})') from None
    if data.shape[0] < 2:
        raise ValueError(f'{path}: fewer than 2 data rows')
    out = {c: data[:, i] for i, c in enumerate(columns)}
    for c, v in out.items():
        if not np.all(np.isfinite(v)):
            raise ValueError(f'{path}: column {c} holds nan/inf values')
    return out


def write_csv_columns(path, columns: dict) -> str:
    """Atomically write equal-length ``columns`` (name -> array) as CSV with a header."""
    path = os.fspath(path)
    names = list(columns)
    data = np.column_stack([np.asarray(columns[n], dtype=float) for n in names])
    with atomic_open(path) as handle:
        np.savetxt(handle, data, delimiter=',', header=','.join(names), comments='',
                   fmt='%.10g')
    return path
