"""The one column-file reader: names or indices, units to SI, refusals that name the problem."""

import numpy as np
import pytest

from rths_common.columns import read_columns, read_header


def _write(tmp_path, text, name='r.csv'):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_names_units_and_comments(tmp_path):
    path = _write(tmp_path, '# a lab comment\ntime [s], stroke [mm], force [kN]\n'
                            '0.0, 1.0, 2.0\n0.5, -2.5, 0.25\n# trailing note\n1.0, 0, 0\n')
    col = read_columns(path, ('time', 'stroke', 'force'))
    assert np.allclose(col['time'], [0.0, 0.5, 1.0])
    assert np.allclose(col['stroke'], [1e-3, -2.5e-3, 0.0])     # mm -> m
    assert np.allclose(col['force'], [2000.0, 250.0, 0.0])      # kN -> N
    assert read_header(path) == ['time', 'stroke', 'force']


def test_indices_whitespace_and_caller_units(tmp_path):
    # no header, tab and space separated, acceleration in g given by the caller's contract
    path = _write(tmp_path, '0.00\t0.5\n0.01  -1.0\n0.02\t0\n', 'r.txt')
    col = read_columns(path, {'t': 0, 'a': 1}, units={'a': 'g'})
    assert np.allclose(col['a'], [0.5 * 9.80665, -9.80665, 0.0])
    assert read_header(path) == []


def test_refusals_name_file_column_and_fix(tmp_path):
    path = _write(tmp_path, 'time,command\n0,1\n0.1,2\n')
    with pytest.raises(ValueError, match=r'missing column\(s\) measured \(header has time, '
                                         r'command\)'):
        read_columns(path, ('time', 'command', 'measured'))
    with pytest.raises(ValueError, match='line 3, column command: .x. is not a number'):
        read_columns(_write(tmp_path, 'time,command\n0,1\n0.1,x\n', 'x.csv'), ('time', 'command'))
    with pytest.raises(ValueError, match='line 2, column command holds nan'):
        read_columns(_write(tmp_path, 'time,command\n0,nan\n0.1,1\n', 'n.csv'), ('time', 'command'))
    with pytest.raises(ValueError, match='unit .furlong. is not known'):
        read_columns(_write(tmp_path, 'time [s],x [furlong]\n0,1\n1,2\n', 'u.csv'), ('time', 'x'))
    with pytest.raises(ValueError, match='has no unit'):
        read_columns(path, ('time', 'command'), require_units=True)
    with pytest.raises(ValueError, match='truncated'):
        read_columns(_write(tmp_path, 'time,command\n0,1\n0.1\n', 't.csv'), ('time', 'command'))
    with pytest.raises(OSError, match='not found'):
        read_columns(tmp_path / 'missing.csv', ('time',))


def test_keep_nan_leaves_empty_cells_to_the_caller(tmp_path):
    col = read_columns(_write(tmp_path, 'time,x\n0,1\n0.1,\n0.2,3\n'), ('time', 'x'),
                       keep_nan=True)
    assert np.isnan(col['x'][1]) and col['x'][2] == 3.0
