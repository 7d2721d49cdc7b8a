"""Scenarios: what one run of a study computes, and the registry the SPEC's ``kind`` names.

A scenario declares its settings (fixed for the whole study), the parameters a study
may vary, the controllers and records it takes, the metrics it returns and how many
runs one Dask task should carry (``chunk``: runs that advance in one vectorised loop).
:meth:`Scenario.evaluate` computes a chunk and must give every run the numbers it
would get alone: a run's result depends on its own inputs only (``test_scenarios``
checks it bit for bit), which is what makes resuming, retrying on another worker and
comparing with a serial run exact.

The scenarios live in their own modules and are imported only when a SPEC names them
(:data:`REGISTRY`), so a worker loads only what its study needs.
"""

import importlib
import time

import numpy as np

from .setting import Setting

#: kind -> "module:class" of every scenario.
REGISTRY = {
    'benchmark': 'rths_study.scenario_benchmark:BenchmarkScenario',
    'design': 'rths_study.scenario_benchmark:DesignScenario',
    'dtm-tuning': 'rths_study.scenario_dtm:DtmTuningScenario',
    'building-frequency': 'rths_study.scenario_dtm:BuildingFrequencyScenario',
    'rths-offline': 'rths_study.scenario_rths:RthsOfflineScenario',
    'cluster-check': 'rths_study.scenarios:ClusterCheckScenario',
}


class Scenario:
    """Base of every scenario (see the module doc)."""

    kind = ''
    summary = ''
    settings: dict = {}             #: name -> Setting, fixed for a study
    parameters: dict = {}           #: name -> Setting, what a study may vary
    controllers: tuple | None = ()  #: allowed controller names; () takes none
    default_controllers: tuple = ()
    uses_records = False
    default_records: tuple = ()
    metrics: dict = {}              #: name -> 'float' or 'bool'
    chunk = 1                       #: default runs per task
    version = 1                     #: part of every run key: raise it when results change

    def check(self, spec) -> None:
        """Check what a field-by-field check cannot (files present, combinations)."""

    def evaluate(self, settings: dict, runs: list) -> list:
        """Return the metrics (a dict) of each run of ``runs`` (``Run.as_dict()`` forms)."""
        raise NotImplementedError


_CACHE: dict = {}


def get(kind: str) -> Scenario:
    """Return the scenario ``kind`` (one instance per process)."""
    if kind not in _CACHE:
        if kind not in REGISTRY:
            raise ValueError(f'scenario {kind!r} unknown; known: {", ".join(REGISTRY)}')
        module, name = REGISTRY[kind].split(':')
        _CACHE[kind] = getattr(importlib.import_module(module), name)()
    return _CACHE[kind]


class ClusterCheckScenario(Scenario):
    """A cheap, seeded computation to try a new cluster (and the runner) end to end.

    Each run draws ``work`` normal numbers from its own stream and returns their mean and
    standard deviation: the same inputs give the same numbers on every machine with the
    same numpy.  ``fail_above`` makes runs with ``x`` above it raise (to see how a study
    records a failing run); ``sleep_s`` stretches each run (to watch a worker die mid-task).
    """

    kind = 'cluster-check'
    summary = 'seeded random numbers per run: try a cluster, a failing run, a dead worker'
    settings = {'work': Setting(int, 10000, minimum=1, maximum=10 ** 8,
                                doc='normal draws per run'),
                'sleep_s': Setting(float, 0.0, minimum=0.0, maximum=3600.0,
                                   doc='seconds each run waits before returning'),
                'fail_above': Setting(float, None, doc='runs with x above this raise')}
    parameters = {'x': Setting(float), 'y': Setting(float)}
    metrics = {'mean': 'float', 'std': 'float', 'x_plus_y': 'float'}
    chunk = 4

    def evaluate(self, settings, runs):
        """Draw and summarise; raise for ``x > fail_above``."""
        out = []
        for run in runs:
            p = run['params']
            x, y = p.get('x', 0.0), p.get('y', 0.0)
            if settings['fail_above'] is not None and x > settings['fail_above']:
                raise ValueError(f'x = {x:g} is above fail_above = {settings["fail_above"]:g}')
            if settings['sleep_s']:
                time.sleep(settings['sleep_s'])
            draws = np.random.default_rng(run['seed']).standard_normal(settings['work'])
            out.append({'mean': float(draws.mean()) + x, 'std': float(draws.std()),
                        'x_plus_y': x + y})
        return out
