"""Studies at scale: robustness, design and tuning sweeps spread over a Dask cluster.

Modules, bottom-up:

* :mod:`.setting`   a typed, checked setting (scenario settings and parameters)
* :mod:`.spec`      the SPEC file: read, check every field, expand into keyed runs
* :mod:`.scenarios` what one run is: the registry of scenarios and their evaluations
* :mod:`.store`     the result table: one Parquet row per run, written as runs finish
* :mod:`.worker`    the function a Dask worker runs on a chunk of runs
* :mod:`.runner`    the study loop: cluster, submission, retries, progress, Ctrl-C
* :mod:`.report`    summary.json, plots and the HTML page of a finished study
* :mod:`.bench`     ``rths bench study``: speed-up, worker loss, serial equality, resume
* :mod:`.cli`       ``rths study run`` and ``rths bench study``
"""
