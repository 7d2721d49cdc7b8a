"""The study SPEC: read the YAML file, check every field, expand it into keyed runs.

A SPEC is a YAML mapping (examples in ``config/studies/``)::

    study: benchmark-perturbed        # name, shown in titles and the summary
    scenario:                         # what one run is (rths_study.scenarios)
      kind: benchmark                 # benchmark, dtm-tuning, building-frequency, rths, design
      case: '1'                       # ...and the scenario's own settings
    parameters:                       # exactly one of grid, random, list (none: one run)
      random:
        n: 1000
        seed: 2020
        draws:
          b1: {normal: {mean: 425.0, std: 3.3}}
          k_e: {uniform: {low: 1.1e6, high: 1.3e6}}
    controllers: [example, fir]       # where the scenario takes a controller
    records: ['gmspy:imperial_valley']  # where the scenario takes a ground-motion record
    metrics: [J1, J2, J3, unstable]   # kept in the table (default: all the scenario's)
    seed: 0                           # of each run's own random stream (sensor noise)
    execution: {chunk: 20, retries: 1}   # runs per task (default: the scenario's)

``grid`` maps each parameter to a list of values or ``{start, stop, num}`` (evenly
spaced, ends included); the runs are their Cartesian product in the SPEC's order.
``random`` draws ``n`` points, point ``i`` from its own stream ``(seed, i)``, so a
larger ``n`` keeps the first points.  ``list`` gives the points one by one.

Every parameter point runs with every controller and every record.  Each run is keyed
by a hash of everything that decides its result (:func:`run_key`): the scenario and
its settings, the parameters, the controller, the record and its seed.  Two SPECs that
share a run share its key, so a rerun into the same directory skips it.

Everything is checked here, before a cluster starts: a bad field raises ValueError
naming the file and the field.
"""

from dataclasses import dataclass, field
import hashlib
import itertools
import json
from pathlib import Path

import numpy as np
import yaml

from . import scenarios
from .scenarios import get
from .setting import Setting, check_mapping

TOP_LEVEL = ('study', 'scenario', 'parameters', 'controllers', 'records', 'metrics', 'seed',
             'execution')
EXECUTION = {'chunk': Setting(int, None, minimum=1, doc='runs per Dask task'),
             'retries': Setting(int, 1, minimum=0, maximum=10,
                                doc='new tries of a task whose worker raised outside the run')}
DISTRIBUTIONS = {'normal': ('mean', 'std'), 'uniform': ('low', 'high')}


@dataclass(frozen=True)
class Run:
    """One run of a study: the inputs of one row of the table."""

    key: str
    index: int
    params: dict
    controller: str | None
    record: str | None
    seed: int

    def as_dict(self) -> dict:
        """Return the run as plain data (what a Dask task carries)."""
        return {'key': self.key, 'index': self.index, 'params': self.params,
                'controller': self.controller, 'record': self.record, 'seed': self.seed}


@dataclass
class Spec:
    """A checked SPEC (see the module doc); :meth:`runs` expands it."""

    source: str
    study: str
    kind: str
    settings: dict
    layout: str                 #: grid, random, list or single
    points: list                #: parameter dicts, in order
    axes: dict = field(default_factory=dict)     #: grid: name -> values
    controllers: list = field(default_factory=lambda: [None])
    records: list = field(default_factory=lambda: [None])
    metrics: list = field(default_factory=list)
    seed: int = 0
    chunk: int = 1
    retries: int = 1
    raw: dict = field(default_factory=dict)

    @property
    def parameter_names(self) -> list:
        """Names of the varied parameters, in SPEC order."""
        return list(self.points[0]) if self.points else []

    def runs(self) -> list:
        """Every run: each point with each controller and each record, keyed."""
        out = []
        for point in self.points:
            for record in self.records:
                seed = run_seed(self.seed, point, record)
                for controller in self.controllers:
                    key = run_key(self.kind, self.settings, point, controller, record, seed)
                    out.append(Run(key, len(out), point, controller, record, seed))
        return out


def canonical(obj) -> str:
    """JSON text that is the same for equal inputs (sorted keys, exact float repr)."""
    return json.dumps(obj, sort_keys=True, separators=(',', ':'), allow_nan=False)


def _digest(obj) -> bytes:
    return hashlib.sha256(canonical(obj).encode()).digest()


def run_seed(seed: int, params: dict, record) -> int:
    """Seed of a run's own random stream: from the study seed, its parameters and record.

    Not from the controller: every controller meets the same noise on the same plant.
    """
    return int.from_bytes(_digest({'seed': seed, 'params': params, 'record': record})[:8],
                          'little') >> 1


def run_key(kind, settings, params, controller, record, seed) -> str:
    """Hash (hex, 24 digits) of every input of a run."""
    version = get(kind).version
    return _digest({'scenario': kind, 'version': version, 'settings': settings,
                    'params': params, 'controller': controller, 'record': record,
                    'seed': seed}).hex()[:24]


# ----------------------------------------------------------------------------- reading
def load_spec(path) -> Spec:
    """Read and check a SPEC file (ValueError/OSError naming the file and field)."""
    path = Path(path)
    if not path.is_file():
        raise OSError(f'{path}: no such SPEC file')
    try:
        raw = yaml.safe_load(path.read_text())
    except yaml.YAMLError as err:
        raise ValueError(f'{path}: not valid YAML ({err})') from None
    return check_spec(raw, str(path))


def check_spec(raw, source: str = 'SPEC') -> Spec:
    """Check a SPEC given as a mapping; return the :class:`Spec`."""
    try:
        return _check(raw)
    except ValueError as err:
        raise ValueError(f'{source}: {err}') from None


def _check(raw) -> Spec:
    if not isinstance(raw, dict):
        raise ValueError('expected a mapping with study, scenario, parameters, ...')
    unknown = sorted(set(raw) - set(TOP_LEVEL))
    if unknown:
        raise ValueError(f'{unknown[0]}: unknown field; known: {", ".join(TOP_LEVEL)}')
    study = Setting(str, 'study').value(raw.get('study'), 'study')
    scen = raw.get('scenario')
    if not isinstance(scen, dict) or 'kind' not in scen:
        raise ValueError('scenario: required, a mapping with kind: one of '
                         + ', '.join(scenarios.REGISTRY))
    kind = Setting(str, choices=tuple(scenarios.REGISTRY)).value(scen['kind'], 'scenario.kind')
    scenario = scenarios.get(kind)
    settings = check_mapping({k: v for k, v in scen.items() if k != 'kind'},
                             scenario.settings, 'scenario')
    layout, points, axes = _parameters(raw.get('parameters'), scenario.parameters)
    controllers = _names(raw.get('controllers'), 'controllers', scenario.controllers,
                         scenario.default_controllers)
    records = _names(raw.get('records'), 'records', None if scenario.uses_records else (),
                     scenario.default_records)
    metrics = _names(raw.get('metrics'), 'metrics', tuple(scenario.metrics),
                     list(scenario.metrics))
    seed = Setting(int, 0, minimum=0).value(raw.get('seed'), 'seed')
    execution = check_mapping(raw.get('execution'), EXECUTION, 'execution')
    spec = Spec(source='', study=study, kind=kind, settings=settings, layout=layout,
                points=points, axes=axes, controllers=controllers or [None],
                records=records or [None], metrics=metrics, seed=seed,
                chunk=execution['chunk'] or scenario.chunk, retries=execution['retries'],
                raw=raw)
    scenario.check(spec)
    return spec


def _names(raw, where, allowed, default) -> list:
    """Check a list of distinct names; ``allowed`` None: any text; (): field refused."""
    if raw is None:
        return list(default)
    if allowed == ():
        raise ValueError(f'{where}: this scenario takes none; remove the field')
    if isinstance(raw, str):
        raw = [raw]
    if not isinstance(raw, list) or not raw:
        raise ValueError(f'{where}: expected a non-empty list')
    text = Setting(str, choices=tuple(allowed) if allowed else ())
    out = [text.value(v, f'{where}[{i}]') for i, v in enumerate(raw)]
    if len(set(out)) != len(out):
        raise ValueError(f'{where}: {out} names one twice')
    return out


def _parameters(raw, known: dict):
    """``(layout, points, grid axes)`` of the ``parameters`` field."""
    if raw is None or raw == {}:
        return 'single', [{}], {}
    layouts = ('grid', 'random', 'list')
    if not isinstance(raw, dict) or len(raw) != 1 or next(iter(raw)) not in layouts:
        raise ValueError('parameters: expected exactly one of grid, random, list')
    layout, body = next(iter(raw.items()))
    where = f'parameters.{layout}'
    if layout == 'grid':
        if not isinstance(body, dict) or not body:
            raise ValueError(f'{where}: expected a mapping of parameter: values')
        axes = {name: _axis(values, _known(known, name, where), f'{where}.{name}')
                for name, values in body.items()}
        points = [dict(zip(axes, combo, strict=True))
                  for combo in itertools.product(*axes.values())]
        return layout, points, axes
    if layout == 'random':
        return layout, _random(body, known, where), {}
    if not isinstance(body, list) or not body:
        raise ValueError(f'{where}: expected a non-empty list of parameter mappings')
    names = None
    points = []
    for i, point in enumerate(body):
        if not isinstance(point, dict) or not point:
            raise ValueError(f'{where}[{i}]: expected a mapping of parameter: value')
        if names is not None and list(point) != names:
            raise ValueError(f'{where}[{i}]: names {list(point)}, the first point {names}: '
                             'give every point the same parameters')
        names = list(point)
        points.append({n: _known(known, n, f'{where}[{i}]').value(v, f'{where}[{i}].{n}')
                       for n, v in point.items()})
    return layout, points, {}


def _known(known: dict, name, where) -> Setting:
    if name not in known:
        raise ValueError(f'{where}.{name}: not a parameter of this scenario; known: '
                         + ', '.join(sorted(known)))
    return known[name]


def _axis(values, setting: Setting, where) -> list:
    if isinstance(values, dict):
        spaced = check_mapping(values, {'start': Setting(float, None), 'stop': Setting(float, None),
                                        'num': Setting(int, None, minimum=1)}, where)
        if None in spaced.values():
            raise ValueError(f'{where}: give start, stop and num (or a list of values)')
        values = np.linspace(spaced['start'], spaced['stop'], spaced['num']).tolist()
    if not isinstance(values, list) or not values:
        raise ValueError(f'{where}: expected a non-empty list of values or {{start, stop, num}}')
    out = [setting.value(v, f'{where}[{i}]') for i, v in enumerate(values)]
    if len(set(out)) != len(out):
        raise ValueError(f'{where}: a value appears twice')
    return out


def _random(body, known, where) -> list:
    if not isinstance(body, dict):
        raise ValueError(f'{where}: expected a mapping with n, seed and draws')
    unknown = sorted(set(body) - {'n', 'seed', 'draws'})
    if unknown:
        raise ValueError(f'{where}.{unknown[0]}: unknown; known: draws, n, seed')
    n = Setting(int, None, minimum=1).value(body.get('n'), f'{where}.n')
    if n is None:
        raise ValueError(f'{where}.n: required, the number of draws')
    seed = Setting(int, 0, minimum=0).value(body.get('seed'), f'{where}.seed')
    if not isinstance(body.get('draws'), dict) or not body['draws']:
        raise ValueError(f'{where}.draws: expected a mapping of parameter: '
                         '{normal: {mean, std}} or {uniform: {low, high}}')
    laws = {}
    for name, law in body['draws'].items():
        w = f'{where}.draws.{name}'
        setting = _known(known, name, f'{where}.draws')
        if setting.kind is not float:
            raise ValueError(f'{w}: {name} is not a number; draw numbers only, list the rest')
        if not isinstance(law, dict) or len(law) != 1 or next(iter(law)) not in DISTRIBUTIONS:
            raise ValueError(f'{w}: expected {{normal: {{mean, std}}}} or '
                             '{uniform: {low, high}}')
        dist, args = next(iter(law.items()))
        args = check_mapping(args, {a: Setting(float, None) for a in DISTRIBUTIONS[dist]},
                             f'{w}.{dist}')
        if None in args.values():
            raise ValueError(f'{w}.{dist}: give {" and ".join(DISTRIBUTIONS[dist])}')
        bad = args['std'] < 0 if dist == 'normal' else args['high'] < args['low']
        if bad:
            raise ValueError(f'{w}.{dist}: std must be >= 0 and low <= high')
        laws[name] = (dist, args)
    return [_draw(seed, i, laws, known, where) for i in range(n)]


def _draw(seed, i, laws, known, where) -> dict:
    rng = np.random.default_rng([seed, i])
    point = {}
    for name, (dist, a) in laws.items():
        value = (a['mean'] + a['std'] * rng.standard_normal() if dist == 'normal'
                 else rng.uniform(a['low'], a['high']))
        point[name] = float(value)
    for name, value in point.items():   # a draw outside a parameter's range is refused
        known[name].value(value, f'{where}.draws.{name} (draw {i}: {value:.6g})')
    return point
