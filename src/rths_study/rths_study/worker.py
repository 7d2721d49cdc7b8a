"""What a Dask worker runs: one chunk of runs of a scenario, returned as table rows.

:func:`evaluate_chunk` never raises for a run's own failure: when the chunk's vectorised
evaluation raises, each run is evaluated alone, and a run that still raises becomes a
row with ``status: error`` and the message, so one bad plant does not sink its chunk
and the study goes on.  It imports only the scenario it is asked for.

The BLAS runs one thread per worker (``threadpoolctl``) whatever the worker's
environment: a least-squares fit with two threads differs in its last bits from one
with one, and a run must give the same numbers on every worker and in a serial run.
"""

import datetime
import time
import traceback

from .scenarios import get

#: Longest error text kept in a row.
ERROR_CHARS = 2000


def worker_name() -> str:
    """Return the Dask worker's name (its address), ``local`` outside a worker."""
    try:
        # lazy: optional: tried here, refused with a clear message when missing
        from distributed import get_worker
        worker = get_worker()
    except (ImportError, ValueError):
        return 'local'
    return str(worker.address)


def _error_text(err: BaseException) -> str:
    last = traceback.extract_tb(err.__traceback__)[-1:] if err.__traceback__ else []
    where = f' ({last[0].filename.rsplit("/", 1)[-1]}:{last[0].lineno})' if last else ''
    return f'{type(err).__name__}: {err}{where}'[:ERROR_CHARS]


def row(run: dict, metrics: dict | None, names: list, error: str | None, seconds: float,
        worker: str) -> dict:
    """One table row of ``run`` (see :mod:`.store` for the columns)."""
    out = {'key': run['key'], 'index': run['index'], **run['params'],
           'controller': run['controller'], 'record': run['record']}
    out.update({name: (metrics or {}).get(name) for name in names})
    out.update(status='error' if error else 'ok', error=error, seconds=seconds, worker=worker,
               finished=datetime.datetime.now(datetime.timezone.utc))
    return out


def evaluate_chunk(kind: str, settings: dict, runs: list, metrics: list) -> list:
    """Evaluate ``runs`` (``Run.as_dict()`` forms) of scenario ``kind``; one row per run."""
    # lazy: optional dependency (threadpoolctl)
    from threadpoolctl import threadpool_limits
    with threadpool_limits(limits=1):
        return _evaluate(kind, settings, runs, metrics)


def _evaluate(kind, settings, runs, metrics) -> list:
    scenario = get(kind)
    worker = worker_name()
    t0 = time.perf_counter()
    try:
        results = scenario.evaluate(settings, runs)
        errors = [None] * len(runs)
    except Exception as err:            # noqa: BLE001 -- a run's failure is data here
        if len(runs) == 1:
            results, errors = [None], [_error_text(err)]
        else:
            results, errors = [], []
            for run in runs:
                try:
                    results.append(scenario.evaluate(settings, [run])[0])
                    errors.append(None)
                except Exception as one:    # noqa: BLE001
                    results.append(None)
                    errors.append(_error_text(one))
    share = (time.perf_counter() - t0) / len(runs)
    return [row(run, res, metrics, err, share, worker)
            for run, res, err in zip(runs, results, errors, strict=True)]


def error_rows(runs: list, metrics: list, error: str, worker: str = '') -> list:
    """Rows for runs whose task never returned (its workers kept dying, or it was lost)."""
    return [row(run, None, metrics, error[:ERROR_CHARS], float('nan'), worker) for run in runs]
