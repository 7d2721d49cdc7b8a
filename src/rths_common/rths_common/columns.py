"""The one reader of column text files (CSV, TSV, whitespace): columns by name or index, in SI.

Every time series a lab hands rths as text goes through :func:`read_columns`:
identification and compensation runs, DTM characterisation records, discrepancy
records and ground motions.  The file layout it accepts::

    # comment lines (a leading '#') are skipped anywhere
    time [s], command [mm], measured [mm]       <- optional header row
    0.0, 0.0, 0.0
    ...

* delimiter: a comma if the first data line has one, else a tab or runs of spaces;
* header: the first line that is not a comment, unless all its cells are numbers;
  a header cell may carry its unit in brackets, ``force [kN]``, and is then
  matched by the name before the bracket;
* a column is asked for by name (``'time'``, needs a header) or by 0-based index;
* units: each column is converted to SI from the unit of ``units`` (the caller's
  contract, e.g. a record in g) or else from the header's bracket; a unit not in
  :data:`UNITS` is refused, never guessed.

A time column's sampling rate comes from :mod:`rths_common.timebase`.  Every problem
is a ValueError (OSError for a missing file) naming the file, the column or row, and
the fix.
"""

import os
import re

import numpy as np

#: Unit -> factor to SI (metres, seconds, newtons, m/s, m/s^2, volts, amperes).
UNITS = {
    '': 1.0, '-': 1.0, 'si': 1.0,
    's': 1.0, 'ms': 1e-3, 'us': 1e-6,
    'm': 1.0, 'mm': 1e-3, 'cm': 1e-2, 'um': 1e-6, 'in': 0.0254,
    'n': 1.0, 'kn': 1e3, 'lbf': 4.4482216152605, 'kip': 4448.2216152605,
    'm/s': 1.0, 'mm/s': 1e-3, 'cm/s': 1e-2, 'in/s': 0.0254,
    'm/s^2': 1.0, 'm/s2': 1.0, 'mm/s^2': 1e-3, 'cm/s^2': 1e-2, 'gal': 1e-2,
    'g': 9.80665,
    'v': 1.0, 'a': 1.0, 'hz': 1.0,
}

#: Units a lab's displacement and time columns may be given in (``rths identify`` options).
LENGTH_UNITS = ('m', 'mm', 'in')
TIME_UNITS = ('s', 'ms')

_HEADER = re.compile(r'^\s*(?P<name>[^\[\]]*?)\s*(\[(?P<unit>[^\]]*)\])?\s*$')
#: A unit in parentheses, as DAQ software writes it (``Disp (mm)``): taken only when known.
_PAREN_UNIT = re.compile(r'^\s*(?P<name>.*?)\s*\((?P<unit>[^()]*)\)\s*$')


def unit_factor(unit: str, where: str) -> float:
    """Return the factor that takes ``unit`` to SI (ValueError naming the known units)."""
    key = str(unit).strip().lower().replace(' ', '')
    if key not in UNITS:
        raise ValueError(f'{where}: unit {unit!r} is not known; use one of '
                         f'{", ".join(u for u in UNITS if u)}')
    return UNITS[key]


def _name_unit(cell: str):
    """Split a header cell ``name [unit]`` or ``name (unit)`` into ``(name, unit or None)``.

    A parenthesised tail counts as a unit only if it is one of :data:`UNITS`
    (``Disp (mm)``); otherwise it stays part of the name (``force (cell 1)``).
    """
    paren = _PAREN_UNIT.match(cell)
    if paren and paren.group('unit').strip().lower().replace(' ', '') in UNITS:
        return paren.group('name'), paren.group('unit').strip()
    match = _HEADER.match(cell)
    if match is None:
        return cell.strip(), None
    return match.group('name'), match.group('unit')


def _split(line: str, delimiter):
    """Return the cells of ``line``, stripped of blanks and of surrounding double quotes."""
    cells = line.split(delimiter) if delimiter else line.split()
    return [c.strip().strip('"').strip() for c in cells]


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def _lines(path, skip_lines: int = 0):
    """Return the file's non-empty, non-comment lines with their 1-based line numbers."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise OSError(f'{path}: file not found')
    with open(path, encoding='utf-8', errors='replace') as handle:
        return [(i + 1, line.rstrip('\r\n')) for i, line in enumerate(handle)
                if i >= skip_lines and line.strip() and not line.lstrip().startswith('#')]


def read_header(path, delimiter=None) -> list:
    """Return the header's column names (their units stripped), [] if the file has none."""
    lines = _lines(path)
    if not lines:
        return []
    sep = _delimiter(lines, delimiter)
    cells = _split(lines[0][1], sep)
    if all(_is_number(c) for c in cells):
        return []
    return [_name_unit(c)[0] for c in cells]


def _delimiter(lines, delimiter):
    if delimiter is not None:
        return delimiter
    sample = lines[1][1] if len(lines) > 1 else lines[0][1]
    return ',' if ',' in sample else ('\t' if '\t' in sample else None)


def read_columns(path, columns, *, units=None, keep_nan: bool = False, min_rows: int = 2,
                 contract: str = '', delimiter=None, skip_lines: int = 0,
                 require_units: bool = False, report: dict | None = None) -> dict:
    """Read ``columns`` of a column text file; return ``{column: float array in SI}``.

    ``columns``: names (need a header row) or 0-based indices, or a mapping
    ``{output name: name or index}``; None: every named column of the header.
    ``units``: ``{output name: unit}`` of the data (else the header's bracket, else SI).
    ``keep_nan``: an empty or ``nan`` cell becomes NaN (the caller decides); otherwise
    any non-finite value is refused.  ``contract`` is what the user should write (for the
    errors; default: the asked names).  ``min_rows``: fewest data rows.
    ``skip_lines``: leading lines to pass over (a fixed preamble); ``require_units``:
    refuse a column whose unit neither ``units`` nor the header gives.  ``report``, a
    dict, receives ``{output name: (column as in the file, unit applied, where from)}``.
    """
    path = os.fspath(path)
    if columns is None:
        columns = [name for name in read_header(path, delimiter) if name]
    wanted = dict(columns) if isinstance(columns, dict) else {c: c for c in columns}
    need = contract or ', '.join(str(c) for c in wanted.values())
    lines = _lines(path, skip_lines)
    if not lines:
        raise ValueError(f'{path}: empty file; expected a header row and data columns {need}')
    sep = _delimiter(lines, delimiter)
    first = _split(lines[0][1], sep)
    header, header_units = [], []
    if not all(_is_number(c) for c in first):
        for cell in first:
            name, unit = _name_unit(cell)
            header.append(name)
            header_units.append(unit)
        lines = lines[1:]
    index = {}
    missing = []
    for out, col in wanted.items():
        if isinstance(col, (int, np.integer)) and not isinstance(col, bool):
            index[out] = int(col)
        elif col in header:
            index[out] = header.index(col)
        else:
            missing.append(str(col))
    if missing:
        has = f'header has {", ".join(header)}' if header else 'no header row'
        raise ValueError(f'{path}: missing column(s) {", ".join(missing)} ({has}); the file '
                         f'needs columns {need}')
    data = _parse(path, lines, sep, index, header, keep_nan)
    if data.shape[0] < min_rows:
        raise ValueError(f'{path}: {data.shape[0]} data rows; need at least {min_rows}')
    out = {}
    for j, (name, i) in enumerate(index.items()):
        unit = (units or {}).get(name)
        if unit is None and i < len(header_units):
            unit = header_units[i]
        where = f'{path}: column {wanted[name]}'
        if require_units and not unit:
            raise ValueError(f'{where} has no unit; write it in the header in brackets, e.g. '
                             f'{wanted[name]} [m/s^2] or {wanted[name]} [g]')
        out[name] = data[:, j] * unit_factor(unit or '', where)
        if report is not None:
            source = ('option' if (units or {}).get(name) is not None else
                      'header' if unit else 'none given: SI')
            column = header[i] if i < len(header) else f'#{i}'
            report[name] = (column, unit or '', source)
    return out


def _parse(path, lines, sep, index, header, keep_nan):
    """Parse the data lines' wanted cells into a float array (rows x columns)."""
    cols = list(index.values())
    width = max(cols) + 1
    data = np.empty((len(lines), len(cols)))
    for r, (lineno, line) in enumerate(lines):
        cells = _split(line, sep)
        if len(cells) < width and not keep_nan:
            raise ValueError(f'{path}: line {lineno} has {len(cells)} of {width} columns; the '
                             'file may be truncated or damaged: restore the full file')
        for j, i in enumerate(cols):
            cell = cells[i] if i < len(cells) else ''
            try:
                value = float(cell) if cell else np.nan
            except ValueError:
                name = header[i] if i < len(header) else f'#{i}'
                raise ValueError(f'{path}: line {lineno}, column {name}: {cell!r} is not a '
                                 'number') from None
            if not keep_nan and not np.isfinite(value):
                name = header[i] if i < len(header) else f'#{i}'
                what = cell or 'an empty cell'
                raise ValueError(f'{path}: line {lineno}, column {name} holds {what}; every '
                                 'cell must be a finite number')
            data[r, j] = value
    return data
