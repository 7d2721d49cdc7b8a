"""The result table and the worker's chunk evaluation, without a cluster."""

import pyarrow.parquet as pq
import pytest

from rths_study.runner import chunks
from rths_study.spec import check_spec
from rths_study.store import Store, schema_of
from rths_study.worker import evaluate_chunk


def _spec(**settings):
    return check_spec({'study': 't', 'scenario': {'kind': 'cluster-check', 'work': 50,
                                                  **settings},
                       'parameters': {'grid': {'x': [0.0, 1.0, 2.0], 'y': [0.5, 1.5]}}})


def _rows(spec, runs):
    return evaluate_chunk(spec.kind, spec.settings, [r.as_dict() for r in runs], spec.metrics)


def test_a_raising_run_is_an_error_row_and_its_chunk_neighbours_still_run():
    spec = _spec(fail_above=1.5)
    rows = _rows(spec, spec.runs())
    assert [r['status'] for r in rows] == ['ok'] * 4 + ['error'] * 2
    assert rows[4]['error'].startswith('ValueError: x = 2 is above fail_above = 1.5')
    assert rows[4]['mean'] is None and rows[0]['x_plus_y'] == 0.5
    assert all(r['worker'] == 'local' and r['seconds'] >= 0 for r in rows)
    alone = _rows(spec, spec.runs()[1:2])[0]
    assert alone['mean'] == rows[1]['mean']          # a run's numbers do not hang on its chunk


def test_rows_land_in_parquet_and_the_last_row_of_a_run_counts(tmp_path):
    spec = _spec(fail_above=1.5)
    store = Store(tmp_path, schema_of(spec))
    assert store.table().num_rows == 0 and store.finished() == {}
    rows = _rows(spec, spec.runs())
    store.append(rows[3:])
    store.append(rows[:3])
    table = pq.read_table(tmp_path / 'runs')         # what a data person would type
    assert table.num_rows == 6 and 'finished' in table.column_names
    assert store.table().column('index').to_pylist() == list(range(6))
    assert list(store.finished().values()).count('error') == 2
    fixed = _rows(_spec(), spec.runs()[4:5])         # the failed run, retried and now ok
    store.append(fixed)
    assert store.finished()[fixed[0]['key']] == 'ok' and store.table().num_rows == 6
    (tmp_path / 'runs' / '.part-x.parquet.tmp').write_text('half a file')
    assert store.table().num_rows == 6               # an unfinished write is not a row


def test_a_directory_of_another_study_is_refused(tmp_path):
    spec = _spec()
    Store(tmp_path, schema_of(spec)).append(_rows(spec, spec.runs()[:1]))
    other = check_spec({'study': 'u', 'scenario': {'kind': 'cluster-check'},
                        'parameters': {'list': [{'y': 1.0}]}})
    with pytest.raises(ValueError, match='holds a study with other columns'):
        Store(tmp_path, schema_of(other))


def test_chunks_keep_one_controller_and_record_per_task():
    spec = check_spec({'study': 't', 'scenario': {'kind': 'benchmark'},
                       'parameters': {'list': [{'b1': 420.0 + i} for i in range(5)]},
                       'controllers': ['example', 'fir'], 'records': ['gmspy:kobe']})
    tasks = chunks(spec.runs(), 3)
    assert [len(t) for t in tasks] == [3, 2, 3, 2]
    assert all(len({(r.controller, r.record) for r in t}) == 1 for t in tasks)
    assert sorted(r.index for t in tasks for r in t) == list(range(10))
