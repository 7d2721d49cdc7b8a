"""Pre-flight check of a run's params files: every error before anything starts or is written.

The launcher calls :func:`check_config` before it starts a node or creates a
bag, so a bad file stops the run with one clear message (``rths launch``
prints it and exits 2) and leaves nothing half-written.  Each params file is
checked by the same plain-Python core its node uses:

* ``numerical.yaml`` -> :func:`rths_numerical.substructure.make_substructure`
  (and through it the model YAML: symmetric, positive-definite matrices;
  the ground-motion file: complete, uniform time step);
* ``compensator.yaml`` -> :func:`rths_compensator.params.check_compensator_params`
  (known keys; provenance under its own key) and
  :func:`rths_compensator.params.load_compensator_params` (finite taps, stable
  denominator), and its ``fs_hz`` against the loop rate (``fs_hz`` of
  ``numerical.yaml``, :func:`rths_compensator.params.check_sampling_rate`);
* ``bridge.yaml`` -> :func:`rths_actuator_bridge.node.check_bridge_params`
  (known keys, finite limits in SI units) and, for the simulated backend,
  :func:`rths_actuator_bridge.bridge.make_backend`.

On top of that every file is scanned for values no node can use: ``.nan`` /
``.inf``, numbers written with a unit (``'0.254 m'``: the files hold SI
numbers only) and values outside the range the node declares
(:func:`rths_common.params.check_spec`).  Every ValueError names the file,
the field and the fix.
"""

import math
from pathlib import Path
import re

from rths_common import yamlfile
from rths_common.params import NODE_KEYS, check_spec
from rths_compensator.params import (
    check_compensator_params,
    check_sampling_rate,
    compensator_params_from,
)

_UNITS = ('m', 'mm', 'cm', 'in', 'inch', 'inches', 'ft', 's', 'ms', 'us', 'sec', 'hz', 'khz',
          'n', 'kn', 'kg', 'lb', 'lbm', 'lbf', 'kip', 'g', 'm/s', 'mm/s', 'in/s', 'm/s^2',
          'm/s2', '%', 'deg', 'rad', 'kn/m', 'n/m', 'n s/m', 'ns/m')
_NUMBER_WITH_UNIT = re.compile(
    r'^\s*[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?\s*(?P<unit>[^\d\s].*?)\s*$')


def load_params_file(path, node: str) -> dict:
    """``ros__parameters`` of ``node`` in the params file ``path`` (ValueError/OSError)."""
    return params_of(Path(path), yamlfile.load(path), node)


def params_of(path: Path, doc, node: str) -> dict:
    """:func:`load_params_file` of the file ``path`` already parsed into ``doc``."""
    section = doc.get(node) if isinstance(doc, dict) else None
    if not isinstance(section, dict) or not isinstance(section.get('ros__parameters'), dict):
        raise ValueError(f"{path}: expected '{node}:' then 'ros__parameters:' at the top; "
                         'see the file of the same name in config/')
    params = dict(section['ros__parameters'])
    for key, value in params.items():
        check_value(path, key, value)
    # what sizes the build, before anything is built from it (duration_s: 1e9 allocated 37 GiB
    # in make_substructure); the other ranges after the file's own checks, whose messages say
    # more ('inches or mm?'), in check_config
    check_ranges(path, node, {k: v for k, v in params.items() if k in SIZING_KEYS})
    return params


#: Parameters that size what a file's check builds: their ranges are checked first.
SIZING_KEYS = ('duration_s', 'fs_hz')


def check_value(path, key: str, value):
    """Reject non-finite numbers and numbers written with a unit (ValueError names the field)."""
    values = value if isinstance(value, (list, tuple)) else [value]
    for i, item in enumerate(values):
        where = f'{key}[{i}]' if isinstance(value, (list, tuple)) else key
        if isinstance(item, float) and not math.isfinite(item):
            raise ValueError(f'{path}: field {where} = {item}: give a finite number')
        match = _NUMBER_WITH_UNIT.match(item) if isinstance(item, str) else None
        if match and match.group('unit').lower() in _UNITS:
            raise ValueError(f'{path}: field {where} = {item!r} carries a unit; write the number '
                             'alone in the SI unit of the comment next to it (m, N, s, Hz, kg)')


def _wrap(path, node, func, *args):
    try:
        return func(*args)
    except (ValueError, OSError) as err:   # OSError: a file the params name (a plant.yaml)
        text = str(err)
        if str(path) in text:
            raise
        raise type(err)(f'{path}: {node}: {text}') from None


def check_numerical(path) -> dict:
    """Validate ``numerical.yaml`` by building the substructure it describes."""
    # lazy: start-up cost: rclpy (~0.3 s), which this module needs only here
    from rths_numerical.node import NODE_PARAMS

    # lazy: start-up cost: SciPy (~1 s), which this module needs only here
    from rths_numerical.substructure import make_substructure

    params = load_params_file(path, 'numerical')
    core = {k: v for k, v in params.items() if k not in NODE_PARAMS}
    _wrap(path, 'numerical', make_substructure, core)
    return params


def check_compensator(path) -> dict:
    """Validate ``compensator.yaml`` (known keys, taps, denominator, fs_hz)."""
    doc = yamlfile.load(path)   # parsed once (the largest file: the taps)
    params = params_of(Path(path), doc, 'compensator')
    check_compensator_params({k: v for k, v in params.items() if k not in NODE_KEYS}, str(path))
    loaded = _wrap(path, 'compensator', compensator_params_from, doc, str(path))
    # the node's own keys (mode, executor, ...) count for check_modes
    return {**loaded, **{k: v for k, v in params.items() if k in NODE_KEYS}}


def check_rates(config_dir, numerical: dict, compensator: dict) -> None:
    """Refuse taps designed for another rate than the loop's (numerical.yaml fs_hz)."""
    # lazy: start-up cost: SciPy (~1 s), which this module needs only here
    from rths_numerical.substructure import DEFAULTS

    loop_fs = numerical.get('fs_hz', DEFAULTS['fs_hz'])
    check_sampling_rate(compensator, loop_fs, str(Path(config_dir) / 'compensator.yaml'),
                        'fs_hz of numerical.yaml')


#: Timing modes a node knows, and the one it takes when its file gives none.
MODES = ('lockstep', 'realtime')
DEFAULT_MODE = 'lockstep'


def check_modes(config_dir, params: dict, overrides: dict) -> str:
    """Refuse a graph whose nodes would run in different timing modes; return the mode.

    A node in realtime and another in lock-step never exchange a step (the graph idles
    until the timeout), so a mixed graph is refused before anything starts.
    """
    modes = {}
    for node in ('numerical', 'compensator', 'bridge'):
        over = (overrides.get(node) or {}).get('mode')
        if over not in (None, ''):
            modes[node] = (str(over), 'override')
        elif 'mode' in params.get(node, {}):
            modes[node] = (str(params[node]['mode']), f'{node}.yaml')
        else:
            modes[node] = (DEFAULT_MODE, f'{node}.yaml has none: the default')
    for node, (mode, where) in modes.items():
        if mode not in MODES:
            raise ValueError(f'{Path(config_dir) / (node + ".yaml")}: field mode = {mode!r} '
                             f'({where}); use lockstep or realtime')
    if len({m for m, _ in modes.values()}) > 1:
        listed = ', '.join(f'{n} {m} ({w})' for n, (m, w) in modes.items())
        raise ValueError(f'{config_dir}: the nodes would run in different timing modes '
                         f'({listed}); they would never exchange a step. Set one for all with '
                         'rths launch --mode lockstep|realtime, or write the same mode in '
                         'every file')
    return modes['numerical'][0]


def check_bridge(path) -> dict:
    """Validate ``bridge.yaml``: keys, limits, backend settings."""
    # lazy: start-up cost: rclpy (~0.3 s), which this module needs only here
    from rths_actuator_bridge.node import check_bridge_params

    params = load_params_file(path, 'bridge')
    core = _wrap(path, 'bridge', check_bridge_params, params)
    # lazy: start-up cost: SciPy (~1 s), which this module needs only here
    from rths_actuator_bridge.bridge import backend_class, make_backend

    if backend_class(core).in_process:   # build the plant: its own checks run
        _wrap(path, 'bridge', make_backend, core).close()
    return params


#: params file -> checker, in loop order.
CHECKS = (('bridge.yaml', check_bridge), ('compensator.yaml', check_compensator),
          ('numerical.yaml', check_numerical))


def check_config(config_dir, overrides: dict = None) -> None:
    """Check every params file of ``config_dir`` (ValueError/OSError on the first bad one).

    ``overrides`` ({node: {key: value}}, as the launcher applies them) count for the
    timing-mode check (:func:`check_modes`).
    """
    config_dir = Path(config_dir)
    checked = {}
    for name, check in CHECKS:
        path = config_dir / name
        if not path.is_file():
            raise OSError(f'params file {path} not found; give --config a directory holding '
                          f'{", ".join(n for n, _ in CHECKS)}')
        checked[name] = check(path)
    check_modes(config_dir, {n.removesuffix('.yaml'): p for n, p in checked.items()},
                overrides or {})
    for name, params in checked.items():
        check_ranges(config_dir / name, name.removesuffix('.yaml'), params)
    # after the ranges: fs_hz: null (the default for make_substructure) is refused there
    check_rates(config_dir, checked['numerical.yaml'], checked['compensator.yaml'])


def node_schema_of(node: str) -> dict:
    """Return the parameter schema (key -> Spec) the node ``node`` declares."""
    # lazy: start-up cost: the node modules load rclpy (~0.3 s), the cores SciPy (~1 s)
    from rths_actuator_bridge import bridge
    from rths_actuator_bridge import node as bridge_node
    from rths_compensator import node as compensator_node
    from rths_compensator import params as compensator_params
    from rths_numerical import node as numerical_node
    from rths_numerical import substructure

    schema, params = {
        'bridge': (bridge.param_schema, bridge_node.NODE_PARAMS),
        'compensator': (compensator_params.param_schema, compensator_node.NODE_PARAMS),
    }.get(node, (substructure.param_schema, numerical_node.NODE_PARAMS))
    return schema(params)


def check_ranges(path, node: str, params: dict) -> None:
    """Refuse a value outside its declared range or choices, as the node would at start-up."""
    schema = node_schema_of(node)
    for key, value in params.items():
        if key in schema:
            _wrap(path, node, check_spec, key, value, schema[key])
