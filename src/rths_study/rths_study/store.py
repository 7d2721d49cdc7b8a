"""The result table of a study: one Parquet row per run, written as the runs finish.

Layout of the study directory ``DIR``::

    DIR/spec.yaml            the SPEC as given (what the rows answer)
    DIR/runs/part-*.parquet  the rows: one file per finished task, written whole (a file
                             appears by an atomic rename, so a crash or Ctrl-C leaves
                             only complete files)
    DIR/study.log            progress lines and every failure

``pyarrow.parquet.read_table('DIR/runs')`` (or ``pandas.read_parquet``) reads the whole
table.  Columns: ``key`` (the run's hash), ``index`` (its place in the SPEC), the
varied parameters, ``controller``, ``record``, the metrics, ``status`` (ok or error),
``error`` (the message of a failed run), ``seconds`` (the run's share of its task's
wall time), ``worker`` (the Dask worker, ``local`` in-process) and ``finished`` (UTC).

A run can have more than one row (a failed run retried with ``--retry-failed``): the
last one counts (:meth:`Store.table`).
"""

import os
from pathlib import Path
import time
import uuid

from .scenarios import get

#: Columns every study has, besides its parameters and metrics.
RUN_COLUMNS = ('key', 'index')
INPUT_COLUMNS = ('controller', 'record')
STATUS_COLUMNS = ('status', 'error', 'seconds', 'worker', 'finished')
#: Columns that tell how a run went, not what it computed: left out of equality checks.
CIRCUMSTANCE_COLUMNS = ('seconds', 'worker', 'finished')


def schema_of(spec):
    """Return the Arrow schema of a study's rows (columns typed by the scenario)."""
    # lazy: optional dependency (pyarrow)
    import pyarrow as pa

    scenario = get(spec.kind)
    arrow = {float: pa.float64(), int: pa.int64(), str: pa.string(), bool: pa.bool_()}
    fields = [pa.field('key', pa.string()), pa.field('index', pa.int64())]
    fields += [pa.field(name, arrow[scenario.parameters[name].kind])
               for name in spec.parameter_names]
    fields += [pa.field(name, pa.string()) for name in INPUT_COLUMNS]
    fields += [pa.field(name, pa.bool_() if scenario.metrics[name] == 'bool' else pa.float64())
               for name in spec.metrics]
    fields += [pa.field('status', pa.string()), pa.field('error', pa.string()),
               pa.field('seconds', pa.float64()), pa.field('worker', pa.string()),
               pa.field('finished', pa.timestamp('ms', tz='UTC'))]
    return pa.schema(fields)


class Store:
    """The rows of one study directory (see the module doc)."""

    def __init__(self, directory, schema):
        self.dir = Path(directory)
        self.parts = self.dir / 'runs'
        self.schema = schema
        self.parts.mkdir(parents=True, exist_ok=True)
        self._check_existing()

    def _files(self) -> list:
        return sorted(self.parts.glob('part-*.parquet'))

    def _check_existing(self):
        # lazy: optional dependency (pyarrow)
        import pyarrow.parquet as pq
        files = self._files()
        if files and not pq.read_schema(files[0]).equals(self.schema):
            raise ValueError(f'{self.dir}: holds a study with other columns '
                             f'({", ".join(pq.read_schema(files[0]).names)}); give another '
                             '--out or the SPEC that made it')

    def append(self, rows: list) -> Path:
        """Write ``rows`` (dicts with every column) as one new part file; return its path."""
        # lazy: optional dependency (pyarrow)
        import pyarrow as pa
        import pyarrow.parquet as pq
        table = pa.Table.from_pylist(rows, schema=self.schema)
        name = f'part-{time.time_ns():020d}-{uuid.uuid4().hex[:8]}.parquet'
        tmp = self.parts / f'.{name}.tmp'
        pq.write_table(table, tmp)
        os.replace(tmp, self.parts / name)
        return self.parts / name

    def table(self):
        """Every run's last row, in SPEC order (an empty table when nothing ran yet)."""
        # lazy: optional dependency (pyarrow)
        import pyarrow as pa
        import pyarrow.parquet as pq
        files = self._files()
        if not files:
            return self.schema.empty_table()
        table = pa.concat_tables([pq.read_table(f, schema=self.schema) for f in files])
        last = {}
        for i, key in enumerate(table.column('key').to_pylist()):
            last[key] = i                       # files are in write order: the last wins
        keep = sorted(last.values(), key=lambda i: table.column('index')[i].as_py())
        return table.take(pa.array(keep, pa.int64()))

    def finished(self) -> dict:
        """``{key: status}`` of every run with a row."""
        table = self.table()
        return dict(zip(table.column('key').to_pylist(), table.column('status').to_pylist(),
                        strict=True))
