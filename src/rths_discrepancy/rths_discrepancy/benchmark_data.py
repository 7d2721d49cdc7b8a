"""Loaders of the public nonlinear system-identification benchmarks the workflow develops on.

Each loader reads one data set's original files, as its authors publish them, into
:class:`Record` s (named columns at the record's sampling rate), from the data set's folder
of :func:`rths_common.datasets.dataset_dir` unless a directory is given:

- :func:`f16gvt`: F-16 ground vibration test (Noel, Kerschen; ``F16Benchmark.pdf``): shaker
  force [N] and amplifier voltage [V] to three accelerations, 400 Hz, multisines at several
  levels (``F16Data_<name>.csv``; the acceleration unit is the recording's own).
- :func:`cascaded_tanks`: cascaded tanks with overflow (Schoukens, Mattsson, Wigren, Noel;
  ``TanksBenchmark.pdf``): pump voltage to lower-tank level [V], Ts = 4 s, one estimation
  and one test record (``dataBenchmark.csv``).
- :func:`bouc_wen`: Bouc-Wen hysteretic benchmark, simulated by its authors (Noel,
  Schoukens; ``BoucWenBenchmark.pdf``): force [N] to displacement [m] at 750 Hz, the
  training multisine (``train.h5``) and the two test records (``test.h5``, also given as
  ``uval_*.mat`` / ``yval_*.mat``).

Sources and licences: :data:`rths_common.datasets.DATASETS`.
"""

from dataclasses import dataclass
import os
from typing import Optional

import numpy as np

from rths_common import datasets

#: The F-16 records: full-grid multisines at levels 1-7 (even levels are the test records)
#: and the special odd multisines at three levels (one realisation each).
F16_RECORDS = tuple([f'FullMSine_Level{i}' + ('_Validation' if i % 2 == 0 else '')
                     for i in range(1, 8)]
                    + [f'SpecialOddMSine_Level{i}_Validation' for i in range(1, 4)])
F16_COLUMNS = ('Force', 'Voltage', 'Acceleration1', 'Acceleration2', 'Acceleration3')
#: The Bouc-Wen benchmark's sampling rate [Hz] (BoucWenBenchmark.pdf, section 5).
BOUC_WEN_FS_HZ = 750.0


@dataclass
class Record:
    """One record: ``columns`` of equal length sampled at ``fs_hz``, their ``units``."""

    name: str
    fs_hz: float
    columns: dict
    units: dict

    @property
    def n_samples(self) -> int:
        """Length of every column."""
        return len(next(iter(self.columns.values())))


def _folder(name: str, directory: Optional[str]) -> str:
    return directory if directory else str(datasets.dataset_dir(name))


def _csv_with_rate(path: str, rate_column: str):
    """Header names, data of the other columns, and the rate from ``rate_column``'s first row.

    The dynonet CSVs end each row with a comma and give the rate only on the first data row.
    """
    if not os.path.isfile(path):
        raise OSError(f'{path}: no such file')
    with open(path) as fh:
        header = [h.strip().strip('"') for h in fh.readline().split(',')]
        first = fh.readline().split(',')
    if rate_column not in header:
        raise ValueError(f'{path}: no column {rate_column!r} in the header {header}')
    names = [h for h in header if h and h != rate_column]
    rate = float(first[header.index(rate_column)])
    data = np.loadtxt(path, delimiter=',', skiprows=1, usecols=[header.index(n) for n in names],
                      ndmin=2)
    return names, data, rate


def f16gvt(record: str = 'FullMSine_Level1', directory: Optional[str] = None) -> Record:
    """Read the F-16 record ``record`` (a name of :data:`F16_RECORDS`)."""
    if record not in F16_RECORDS:
        raise ValueError(f'F-16 record {record!r}: use one of {", ".join(F16_RECORDS)}')
    path = os.path.join(_folder('f16gvt', directory), f'F16Data_{record}.csv')
    names, data, fs = _csv_with_rate(path, 'Fs')
    if tuple(names) != F16_COLUMNS:
        raise ValueError(f'{path}: columns {names}, expected {list(F16_COLUMNS)}')
    units = {'Force': 'N', 'Voltage': 'V', 'Acceleration1': 'as recorded',
             'Acceleration2': 'as recorded', 'Acceleration3': 'as recorded'}
    return Record(f'f16gvt/{record}', fs, dict(zip(names, data.T, strict=True)), units)


def cascaded_tanks(directory: Optional[str] = None) -> dict:
    """Read ``{'estimation': Record, 'test': Record}``, each with columns u [V] and y [V]."""
    path = os.path.join(_folder('cascaded_tanks', directory), 'dataBenchmark.csv')
    names, data, ts = _csv_with_rate(path, 'Ts')
    col = dict(zip(names, data.T, strict=True))
    for need in ('uEst', 'uVal', 'yEst', 'yVal'):
        if need not in col:
            raise ValueError(f'{path}: no column {need!r}')
    units = {'u': 'V', 'y': 'V'}
    return {'estimation': Record('cascaded_tanks/estimation', 1.0 / ts,
                                 {'u': col['uEst'], 'y': col['yEst']}, units),
            'test': Record('cascaded_tanks/test', 1.0 / ts,
                           {'u': col['uVal'], 'y': col['yVal']}, units)}


def bouc_wen(directory: Optional[str] = None) -> dict:
    """Read ``{'train_multisine', 'test_multisine', 'test_sinesweep'}``: u [N], y [m].

    The rate stored in the HDF5 files must be the benchmark's 750 Hz.
    """
    import h5py
    folder = _folder('bouc_wen', directory)
    out = {}
    for fname, prefix in (('train.h5', 'train'), ('test.h5', 'test')):
        path = os.path.join(folder, fname)
        if not os.path.isfile(path):
            raise OSError(f'{path}: no such file')
        with h5py.File(path, 'r') as h5:
            for group in h5:
                fs = float(np.ravel(h5[group]['fs'][()])[0])
                if fs != BOUC_WEN_FS_HZ:
                    raise ValueError(f'{path}: {group}/fs = {fs:g} Hz, the benchmark is at '
                                     f'{BOUC_WEN_FS_HZ:g} Hz')
                out[f'{prefix}_{group}'] = Record(
                    f'bouc_wen/{prefix}_{group}', fs,
                    {'u': np.ravel(h5[group]['u'][()]), 'y': np.ravel(h5[group]['y'][()])},
                    {'u': 'N', 'y': 'm'})
    return out


def bouc_wen_mat(kind: str = 'multisine', directory: Optional[str] = None) -> Record:
    """Read the benchmark's own test record ``kind`` (multisine, sinesweep) from its .mat files."""
    from scipy.io import loadmat
    if kind not in ('multisine', 'sinesweep'):
        raise ValueError(f'Bouc-Wen test record {kind!r}: use multisine or sinesweep')
    folder = _folder('bouc_wen', directory)
    cols = {}
    for col in ('u', 'y'):
        path = os.path.join(folder, f'{col}val_{kind}.mat')
        if not os.path.isfile(path):
            raise OSError(f'{path}: no such file')
        cols[col] = np.ravel(loadmat(path)[f'{col}val_{kind}'])
    return Record(f'bouc_wen/{kind}', BOUC_WEN_FS_HZ, cols, {'u': 'N', 'y': 'm'})
