"""The runner on real Dask clusters: local, and a scheduler + two workers started over TCP."""

import json
import os
import socket
import subprocess
import sys
import time

import pyarrow.parquet as pq
import pytest
import yaml

from rths_bringup.cli import main
from rths_study.bench import WorkerKiller, comparable, run_bench
from rths_study.runner import run_study
from rths_study.spec import check_spec, load_spec
from rths_study.store import Store, schema_of
from rths_study.worker import evaluate_chunk

SPEC = {'study': 'check', 'scenario': {'kind': 'cluster-check', 'work': 2000,
                                       'fail_above': 8.5},
        'parameters': {'grid': {'x': {'start': 0, 'stop': 9, 'num': 10}, 'y': [1.0, 2.0]}},
        'execution': {'chunk': 4}}


def test_local_study_survives_ctrl_c_resumes_and_reports(tmp_path, capsys):
    path = tmp_path / 'spec.yaml'
    path.write_text(yaml.safe_dump(SPEC))
    spec, out = load_spec(path), tmp_path / 'out'

    def interrupt(client, done, total):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_study(spec, out, workers=2, on_result=interrupt)
    kept = Store(out, schema_of(spec)).table().num_rows
    assert 1 <= kept < 20                                      # the finished task's rows
    code = main(['study', 'run', str(path), '--out', str(out), '--workers', '2'])
    assert code == 1                                           # two runs fail (x = 9)
    assert pq.read_table(out / 'runs').num_rows == 20          # none ran twice
    table = Store(out, schema_of(spec)).table().to_pylist()
    assert [r['status'] for r in table].count('error') == 2
    assert 'above fail_above' in (out / 'study.log').read_text()
    summary = json.loads((out / 'summary.json').read_text())
    assert summary['ok'] == 18 and summary['errors'] == 2 and summary['runs'] == 20
    assert summary['grid_best']['mean']['all']['x'] == 0.0
    for name in ('distributions.png', 'worst.png', 'surface_0.png', 'report.html'):
        assert (out / name).stat().st_size > 1000, name
    assert f'{kept} already in' in capsys.readouterr().out
    stats = run_study(spec, out, workers=1)
    assert stats['skipped'] == 20 and stats['ran'] == 0
    stats = run_study(spec, out, workers=1, retry_failed=True)
    assert stats['ran'] == 2 and stats['errors'] == 2


def test_a_bad_spec_exits_2_naming_the_field(tmp_path, capsys):
    path = tmp_path / 'spec.yaml'
    path.write_text(yaml.safe_dump(dict(SPEC, controllers=['fir'])))
    assert main(['study', 'run', str(path), '--out', str(tmp_path / 'o')]) == 2
    assert 'controllers: this scenario takes none' in capsys.readouterr().err
    assert not (tmp_path / 'o').exists()                       # nothing started


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def test_study_on_a_dask_scheduler_and_two_workers_over_tcp_loses_no_run(tmp_path):
    # `dask scheduler` and two `dask worker` processes (each under its nanny), as on two lab
    # PCs, on the loopback interface; one worker process is killed while busy.
    address = f'tcp://127.0.0.1:{_free_port()}'
    dask = [sys.executable, '-m', 'dask']
    host, port = address[6:].split(':')
    procs = [subprocess.Popen(dask + ['scheduler', '--host', host, '--port', port,
                                      '--no-dashboard'], stderr=subprocess.DEVNULL)]
    try:
        time.sleep(1.0)
        procs += [subprocess.Popen(dask + ['worker', address, '--nthreads', '1',
                                           '--no-dashboard'], stderr=subprocess.DEVNULL)
                  for _ in range(2)]
        spec = check_spec(dict(SPEC, scenario={'kind': 'cluster-check', 'work': 2000,
                                               'sleep_s': 0.15},
                               execution={'chunk': 2}))
        killer = WorkerKiller(after=2)
        stats = run_study(spec, tmp_path, scheduler=address, workers=2, on_result=killer)
        assert stats['workers'] == 2 and killer.killed is not None
        table = Store(tmp_path, schema_of(spec)).table()
        assert table.num_rows == 20 and stats['errors'] == 0
        assert set(table.column('status').to_pylist()) == {'ok'}
        assert len(set(table.column('worker').to_pylist())) >= 2
        serial = evaluate_chunk(spec.kind, spec.settings, [r.as_dict() for r in spec.runs()],
                                spec.metrics)
        assert [r['mean'] for r in table.to_pylist()] == [r['mean'] for r in serial]
    finally:
        for proc in reversed(procs):
            proc.terminate()
        for proc in procs:
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()


def test_bench_fields_on_a_small_study(tmp_path):
    spec = check_spec(dict(SPEC, scenario={'kind': 'cluster-check', 'work': 2000,
                                           'sleep_s': 0.1},
                           parameters={'grid': {'x': [0.0, 1.0, 2.0, 3.0], 'y': [1.0, 2.0]}},
                           execution={'chunk': 2}))
    result = run_bench(spec=spec, work_dir=str(tmp_path), log=lambda msg: None)
    assert list(result) == ['tasks', 'workers', 'serial_s', 'parallel_s', 'speedup',
                            'tasks_lost_after_worker_kill', 'identical_to_serial',
                            'resumed_skipped']
    assert result['tasks'] == 8 and result['workers'] == 2
    assert result['tasks_lost_after_worker_kill'] == 0
    assert result['identical_to_serial'] is True and result['resumed_skipped'] == 8
    assert result['speedup'] == pytest.approx(result['serial_s'] / result['parallel_s'],
                                              rel=1e-2)
    serial = Store(tmp_path / 'serial', schema_of(spec)).table()
    assert comparable(serial) == comparable(Store(tmp_path / 'killed', schema_of(spec)).table())
    assert os.path.isdir(tmp_path / 'parallel' / 'runs')
