"""Run many independent workflow cases: forked workers, one progress line, misses reported.

Used by the self-test bench (:mod:`.selftest`) and the held-out sets (:mod:`.heldout`).
"""

import multiprocessing as mp

from rths_common.progress import Progress


def run_parallel(func, jobs, workers, on_row=None):
    """``[func(job) for job in jobs]`` on ``workers`` forked processes (in finishing order).

    ``on_row(rows)`` is called after each result with the rows so far (progress).
    """
    rows = []
    if workers > 1:
        with mp.get_context('fork').Pool(workers) as pool:
            for row in pool.imap_unordered(func, jobs):
                rows.append(row)
                if on_row:
                    on_row(rows)
    else:
        for job in jobs:
            rows.append(func(job))
            if on_row:
                on_row(rows)
    return rows


def run_with_progress(func, jobs, workers, label, say, line):
    """Run ``func`` over ``jobs`` with a progress line; ``say(line(i, n, row))`` for wrong rows.

    Each row is a dict with a ``correct`` flag; the rows come back in finishing order.
    """
    with Progress(len(jobs), label) as bar:
        def on_row(rows):
            if not rows[-1]['correct']:
                with bar.hidden():
                    say(line(len(rows), len(jobs), rows[-1]))
            bar.update(len(rows))
        return run_parallel(func, jobs, workers, on_row)
