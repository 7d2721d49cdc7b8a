"""The study loop: expand the SPEC, skip what is done, spread the rest over Dask, keep rows.

:func:`run_study` is the whole procedure::

    runs  = spec.runs()                              every run, keyed by its inputs
    todo  = runs without a row in DIR/runs           (a rerun skips finished runs)
    tasks = todo in chunks of spec.chunk             (same record and controller together)
    on a cluster: submit every task; as each one finishes, append its rows to the table
    (one Parquet file per task) and report done/total, rate, ETA and failures

The cluster (:func:`connect`) is a local one on this machine's cores (``workers``
processes of one thread each) or, given ``scheduler`` (``tcp://HOST:8786``), an
existing one started with ``dask scheduler`` / ``dask worker``; nothing else changes.

Nothing lost, nothing twice: a worker that dies mid-task has its task re-run on another
worker by the Dask scheduler (a task whose workers keep dying, ``KilledWorker``, is
recorded as failed); a run that raises is a row with its error; Ctrl-C cancels what is
running and leaves every finished row on disk, and rerunning the command continues.
"""

import contextlib
import datetime
import hashlib
import logging
import os
import time

import yaml

from rths_common.progress import Progress

from . import worker as wk
from .spec import canonical
from .store import Store, schema_of


@contextlib.contextmanager
def connect(scheduler: str | None = None, workers: int | None = None, timeout_s: float = 60.0):
    """Yield a Dask client: of a new local cluster, or of the cluster at ``scheduler``.

    Local: ``workers`` processes (default: this machine's cores), one thread each (each
    run is single-threaded numpy; Dask sets the BLAS threads of its workers to 1).
    Remote: waits until ``workers`` workers have joined, when given.
    """
    # lazy: optional dependency (distributed)
    from distributed import Client, LocalCluster
    if workers is not None and workers < 1:
        raise ValueError(f'--workers must be >= 1, got {workers}')
    if scheduler:
        try:
            client = Client(scheduler, timeout=f'{timeout_s}s')
        except OSError as err:
            raise OSError(f'--scheduler {scheduler}: no Dask scheduler answers there ({err}); '
                          'start one with `dask scheduler` and its workers with '
                          f'`dask worker {scheduler}`') from None
        try:
            if workers:
                client.wait_for_workers(workers, timeout=timeout_s)
            yield client
        finally:
            client.close()
        return
    cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1,
                           processes=True, dashboard_address=':0',
                           silence_logs=logging.ERROR)
    try:
        client = Client(cluster)
        try:
            yield client
        finally:
            client.close()
    finally:
        cluster.close()


def chunks(runs: list, size: int) -> list:
    """Split ``runs`` into tasks of at most ``size``, each of one record and one controller."""
    order = sorted(runs, key=lambda r: (str(r.record), str(r.controller), r.index))
    out, current = [], []
    for run in order:
        if current and (len(current) == size or (run.record, run.controller)
                        != (current[0].record, current[0].controller)):
            out.append(current)
            current = []
        current.append(run)
    return out + ([current] if current else [])


def _task_key(study: str, chunk: list) -> str:

    digest = hashlib.sha256(canonical([r.key for r in chunk]).encode()).hexdigest()[:16]
    return f'rths-study-{study}-{digest}'


class StudyLog:
    """``DIR/study.log``: start, progress lines, every failure, the end."""

    def __init__(self, path):
        self.fh = open(path, 'a', buffering=1)

    def write(self, text: str):
        """Append one time-stamped line."""
        now = datetime.datetime.now().isoformat(timespec='seconds')
        self.fh.write(f'{now} {text}\n')

    def close(self):
        """Close the file."""
        self.fh.close()


def run_study(spec, out_dir, scheduler=None, workers=None, retry_failed=False,
              on_result=None, label=None) -> dict:
    """Run ``spec`` into ``out_dir`` (module doc); return the counts and times.

    ``on_result(client, done, total)`` is called after each task's rows are written
    (``rths bench study`` kills a worker from there).
    """
    store = Store(out_dir, schema_of(spec))
    _save_spec(spec, store.dir)
    runs = spec.runs()
    finished = store.finished()
    todo = [r for r in runs if r.key not in finished
            or (retry_failed and finished[r.key] != 'ok')]
    tasks = chunks(todo, spec.chunk)
    stats = {'runs': len(runs), 'skipped': len(runs) - len(todo), 'ran': 0, 'ok': 0,
             'errors': 0, 'tasks': len(tasks), 'workers': 0, 'wall_s': 0.0,
             'interrupted': False}
    log = StudyLog(store.dir / 'study.log')
    label = label or f'study {spec.study}'
    log.write(f'start: {spec.source or spec.study}: {len(runs)} runs, {stats["skipped"]} '
              f'already done, {len(todo)} to run in {len(tasks)} tasks')
    if not tasks:
        log.write('nothing to run')
        log.close()
        return stats
    with connect(scheduler, workers) as client:
        stats['workers'] = len(client.scheduler_info().get('workers', {}))
        stats['scheduler'] = client.scheduler.address
        log.write(f'cluster {stats["scheduler"]}: {stats["workers"]} workers')
        bar = Progress(len(todo), label, 'runs')
        logbar = Progress(len(todo), label, 'runs', stream=log.fh, log_s=30.0)
        logbar.mode = 'log'
        t0 = time.perf_counter()
        try:
            _collect(client, spec, tasks, store, stats, (bar, logbar), log, on_result)
        except KeyboardInterrupt:
            stats['interrupted'] = True
            log.write(f'interrupted: {stats["ran"]} runs of this session on disk; rerun the '
                      'same command to continue')
            raise
        finally:
            stats['wall_s'] = time.perf_counter() - t0
            bar.close()
            logbar.close()
            log.write(f'end: {stats["ok"]} ok, {stats["errors"]} failed, '
                      f'{stats["wall_s"]:.1f} s')
            log.close()
    return stats


def _collect(client, spec, tasks, store, stats, bars, log, on_result):
    """Submit every task; write each one's rows as it finishes."""
    # lazy: optional dependency (distributed)
    from distributed import as_completed
    futures = {}
    for chunk in tasks:
        fut = client.submit(wk.evaluate_chunk, spec.kind, spec.settings,
                            [r.as_dict() for r in chunk], spec.metrics,
                            key=_task_key(spec.study, chunk), retries=spec.retries)
        futures[fut] = chunk
    total = sum(len(c) for c in tasks)
    try:
        for fut in as_completed(list(futures)):
            chunk = [r.as_dict() for r in futures.pop(fut)]
            try:
                rows = fut.result()
            except Exception as err:        # noqa: BLE001 -- KilledWorker and the like
                rows = wk.error_rows(chunk, spec.metrics, f'{type(err).__name__}: {err}')
            store.append(rows)
            failed = [r for r in rows if r['status'] != 'ok']
            for r in failed:
                log.write(f'run {r["index"]} ({r["key"]}) failed on {r["worker"] or "?"}: '
                          f'{r["error"]}')
            stats['ran'] += len(rows)
            stats['errors'] += len(failed)
            stats['ok'] += len(rows) - len(failed)
            for bar in bars:
                if stats['errors']:
                    bar.label = bar.label.split(' (')[0] + f' ({stats["errors"]} failed)'
                bar.update(stats['ran'])
            if on_result:
                on_result(client, stats['ran'], total)
    finally:
        if futures:
            client.cancel(list(futures))


def _save_spec(spec, directory):
    path = directory / 'spec.yaml'
    tmp = directory / '.spec.yaml.tmp'
    tmp.write_text(yaml.safe_dump(spec.raw, sort_keys=False))
    os.replace(tmp, path)
