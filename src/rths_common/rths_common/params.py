"""The parameter schema of the loop nodes: node-level keys, their descriptions, descriptors.

Each package keeps one registry of its core's keys (default and a description
with the unit in brackets): :data:`rths_numerical.substructure.PARAMS`,
:data:`rths_compensator.params.FILTER_PARAMS`, the bridge's ``SIM_PARAMS``,
``SAFETY_PARAMS``, ``UDP_PARAMS`` and :data:`rths_actuator_bridge.bridge.PARAMS`.
The keys that configure a node itself, not its core, are described here once
(:data:`NODE_KEYS`); each node takes the subset its ``NODE_PARAMS`` names.
Beside each registry a table of ranges (``*_RANGES``: key -> inclusive (low,
high), ints for an integer parameter) bounds the rates, limits, gains and counts,
and a table of choices (``*_CHOICES``: key -> the allowed values, most often a
:class:`rths_common.registry.Registry`'s names) closes the keys that name a
specimen, a scheme, a method or a backend.
:func:`node_schema` joins them into the node's schema (key -> :class:`Spec`) and
:func:`rths_common.node_support.make_node` turns it into ROS parameter
descriptors (type, range, read-only, description with the choices), so ``ros2
param describe`` shows them; :func:`check_spec` gives the error of a value outside
its range or its choices.  :func:`renamed` accepts a key under its former name
with a one-line deprecation note.
"""

import argparse
import sys
from typing import NamedTuple

#: Parameters that configure a node itself, not its core (the union of the nodes'
#: NODE_PARAMS; test_offline_node_keys checks it), with their descriptions.
NODE_KEYS = {
    'mode': 'lockstep | realtime: lock-step exchange or the fixed-rate loop',
    'executor': 'events (rclpy EventsExecutor) | single (SingleThreadedExecutor)',
    'wait_for_subscribers': '[-] readers of the output topic to wait for before step 0',
    'wait_for_stop_readers': '[-] monitor in stop mode: readers of /rths/emergency_stop to '
                             'wait for before step 0 (the bridge; the recorder too with a bag)',
    'status_every': '[steps] publish a LoopStatus every N steps (and on every miss)',
    'history_out': '.npz path for the response history (empty: none)',
    'timing_out': '.npz path for per-step timing of the loop benchmark (empty: none)',
    'remote_graph': 'true: the other nodes run on other hosts (docs/lab_network.md)',
    'autostart': 'configure and activate at start-up',
    'watchdog_timeout_s': '[s] lock-step: no command for this long -> safe stop',
    'clock': 'loop | thread | timer: what ticks the realtime bridge',
    'spin_margin_us': '[us] loop clock: poll the last part of each period',
    'direct_delivery': 'composed layout, realtime, loop clock: the loop messages go between '
                       'the three nodes by direct calls (over DDS only to readers outside '
                       'the process)',
    'publish_specimen': 'auto | true | false: publish /rths/specimen',
    'command_source': 'node name whose /rths/command is accepted; others are refused',
    'rt_priority': '[-] SCHED_FIFO priority in realtime mode (-1: the node default, 0: none)',
    'cpus': "CPU affinity, e.g. '1' or '0-1' ('' = all)",
    'gc': 'auto | default | freeze | disable: the Python garbage collector (auto: freeze '
          'in realtime mode)',
    'coefficients_every': '[steps] adaptive compensator: publish its coefficients every N steps',
    'run_id': "the run's identity (the launcher gives one per run): messages of another "
              'run are ignored',
    'loop_fs_hz': '[Hz] the loop rate (fs_hz of numerical.yaml and bridge.yaml; rths launch '
                  'passes it): the taps must be designed for it',
}

#: Range of every loop rate (``fs_hz``, ``loop_fs_hz``) [Hz], inclusive: beyond it a value is
#: almost surely in the wrong unit or a typo.
LOOP_RATE_RANGE_HZ = (1.0, 100_000.0)

#: Range of ``rate_divisor`` (loop steps per numerical step, rths_numerical.multirate),
#: inclusive: 4096 Hz / 64 = 64 Hz still samples a building's modes.
RATE_DIVISOR_RANGE = (1, 64)

#: Most steps one run may have (``duration_s`` x ``fs_hz``): 2**24, 4.5 h at 1024 Hz or 68 min
#: at 4096 Hz, 134 MB for each per-step float64 array the run holds.  The ranges of the two
#: alone allowed 1e6 s at 1024 Hz: ~8 GB for one array, allocated before anything could fail.
MAX_RUN_STEPS = 2 ** 24


def check_run_steps(duration_s: float, fs_hz: float, where: str = 'parameter') -> int:
    """Return the steps of a run of ``duration_s`` at ``fs_hz``; ValueError beyond MAX_RUN_STEPS."""
    steps = int(round(float(duration_s) * float(fs_hz)))
    if steps > MAX_RUN_STEPS:
        raise ValueError(
            f'{where} duration_s = {duration_s:g} s at fs_hz = {fs_hz:g} Hz is {steps} steps, '
            f'more than one run holds ({MAX_RUN_STEPS}, {MAX_RUN_STEPS / fs_hz / 3600:.2g} h at '
            'this rate): split the test into several runs or check the unit (s, not ms)')
    return steps


#: Ranges of the node-level keys (inclusive; ints for an integer parameter).
NODE_RANGES = {
    'wait_for_subscribers': (0, 64),
    'wait_for_stop_readers': (0, 64),
    'status_every': (1, 1_000_000),
    'watchdog_timeout_s': (0.01, 3600.0),
    'spin_margin_us': (0.0, 100_000.0),
    'rt_priority': (-1, 99),
    'coefficients_every': (1, 1_000_000),
    'loop_fs_hz': LOOP_RATE_RANGE_HZ,
}


#: Allowed values of the node-level keys that take one of a few words.
NODE_CHOICES = {
    'mode': ('lockstep', 'realtime'),
    'executor': ('events', 'single'),
    'clock': ('loop', 'thread', 'timer'),
    'gc': ('auto', 'default', 'freeze', 'disable'),
}


class Spec(NamedTuple):
    """One parameter of a node's schema: what it is (unit in brackets), its range, its choices."""

    description: str
    range: tuple | None = None   # inclusive (low, high); ints: an integer parameter
    choices: tuple | None = None  # the allowed values (None: any value of the type)
    per_channel: bool = False    # a list of one value per actuator channel is allowed too

    def text(self) -> str:
        """Return the description with the allowed values (what ``ros2 param describe`` shows)."""
        text = self.description
        if self.per_channel:
            text += ' (one number for every actuator, or a list of one per actuator)'
        if not self.choices:
            return text
        return f'{text} (one of: {choices_text(self.choices)})'


def choices_text(choices, sep: str = ', ') -> str:
    """Return the allowed values as a user reads them: ``a, b, c``."""
    return sep.join(str(c) for c in choices)


def core_params(params: dict) -> dict:
    """Return ``params`` without the node-level keys."""
    return {k: v for k, v in params.items() if k not in NODE_KEYS}


def node_schema(node_params, core: dict, ranges: dict | None = None,
                choices: dict | None = None, per_channel=()) -> dict:
    """Return the schema (key -> :class:`Spec`) of a node: its node-level keys and its core's.

    ``core`` maps a key to a description, or to a tuple whose last item is
    the description (the packages' registries); ``ranges`` and ``choices`` are
    the core's (the node-level keys take theirs from :data:`NODE_RANGES` and
    :data:`NODE_CHOICES`); the core's keys in ``per_channel`` take a list of one
    value per actuator channel as well as one number (each value in the range).
    """
    ranges = {**NODE_RANGES, **(ranges or {})}
    allowed = {**NODE_CHOICES, **(choices or {})}
    schema = {key: Spec(NODE_KEYS[key], ranges.get(key), _tuple(allowed.get(key)))
              for key in node_params}
    for key, spec in core.items():
        text = spec[-1] if isinstance(spec, tuple) else str(spec)
        schema[key] = Spec(text, ranges.get(key), _tuple(allowed.get(key)),
                           key in per_channel)
    return schema


def _tuple(choices):
    return None if choices is None else tuple(choices)


def check_spec(key: str, value, spec: Spec) -> None:
    """Refuse a value outside ``spec``'s range or choices (ValueError naming key, values, fix)."""
    if spec.choices is not None and value not in spec.choices:
        raise ValueError(f'parameter {key} = {value!r} is not one of {choices_text(spec.choices)}; '
                         f'fix it in the params file ({spec.description})')
    check_range(key, value, spec)


def check_range(key: str, value, spec: Spec) -> None:
    """Refuse a value outside ``spec.range`` (ValueError naming the parameter, range and fix).

    A non-number for a ranged parameter is refused too (a bool is not a number).  A
    per-channel parameter (:attr:`Spec.per_channel`) may be a non-empty list: each value
    is checked, the message names it as ``key[i]``.
    """
    if spec.range is None:
        return
    if spec.per_channel and isinstance(value, (list, tuple)):
        if not value:
            raise ValueError(f'parameter {key} is an empty list; give one number for every '
                             f'actuator or one per actuator ({spec.description})')
        for i, item in enumerate(value):
            check_range(f'{key}[{i}]', item, spec._replace(per_channel=False))
        return
    low, high = spec.range
    span = f'[{_num(low)}, {_num(high)}]'
    unit = spec.description.split(']')[0] + ']' if spec.description.startswith('[') else ''
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        problem = f'must be a number in {span}'
    elif not low <= value <= high:   # also refuses nan
        problem = f'is outside its range {span}'
    elif isinstance(low, int) and isinstance(high, int) and value != int(value):
        problem = f'must be an integer in {span}'
    else:
        return
    raise ValueError(f'parameter {key} = {value!r} {problem} {unit}; fix it in the params '
                     f'file ({spec.description})')


def _num(value) -> str:
    """``value`` as written in a range: an int as it is, a float in ``%g``."""
    return str(value) if isinstance(value, int) else f'{value:g}'


#: (old, new, where) already noted by :func:`renamed`: each note is printed once.
_NOTED: set = set()


def renamed(params: dict, old: str, new: str, where: str) -> dict:
    """Return ``params`` with the key ``old`` renamed ``new`` and a one-line note on stderr.

    Keys under their former name are accepted for a while; the note names the file or
    option to change.  Both given: the one given last wins (an override of a file that
    already has the new key), as a later line of a file would.
    """
    if old not in params:
        return params
    keys = list(params)
    later = old if new not in params or keys.index(old) > keys.index(new) else new
    if (old, new, where) not in _NOTED:
        _NOTED.add((old, new, where))
        both = (f'; both are given, the later ({later}: {params[later]!r}) is used'
                if new in params and params[new] != params[old] else '')
        print(f'note: {where}: {old!r} is now called {new!r}; the old name is accepted for '
              f'now, rename it{both}', file=sys.stderr)
    out = {k: v for k, v in params.items() if k != old}
    out[new] = params[later]
    return out


def add_renamed_option(parser, old: str, new: str) -> None:
    """Accept the command-line option ``old`` (hidden from --help) as ``new``, with a note.

    ``new`` must already be an option of ``parser``; ``old`` stores into its ``dest``.
    """
    target = next(a for a in parser._actions if new in a.option_strings)

    class Renamed(argparse.Action):
        def __call__(self, parser, namespace, values, option_string=None):
            print(f'note: {old} is now called {new}; the old name is accepted for now',
                  file=sys.stderr)
            if target.choices is not None and values not in target.choices:
                parser.error(f'argument {new}: invalid choice: {values!r} (choose from '
                             f'{", ".join(map(str, target.choices))})')
            setattr(namespace, target.dest, values)

    parser.add_argument(old, action=Renamed, help=argparse.SUPPRESS, metavar=target.metavar)


#: Ranges of the ``rths`` command-line options (by option string, inclusive; ints for an integer
#: option): every command that has one of these options refuses a value outside its range
#: while parsing, before it starts anything (:func:`check_option_ranges`).
OPTION_RANGES = {
    **{opt: Spec('[Hz] loop rate', LOOP_RATE_RANGE_HZ)
       for opt in ('--rate', '--fs-hz', '--fs-max')},
    **{opt: Spec('[s] duration', (0.0, 1e6))
       for opt in ('--duration', '--duration-s', '--ident-duration', '--benchmark-duration',
                   '--record-s', '--blwn-s', '--chirp-s', '--eval-s', '--timeout',
                   '--wait-timeout')},
    **{opt: Spec('[ms] delay', (0.0, 100_000.0))
       for opt in ('--delay-ms', '--jitter-ms', '--one-way-ms')},
    '--loss-pct': Spec('[%] loss', (0.0, 100.0)),
    '--live-rate': Spec('[Hz] live view rate', (0.1, 1000.0)),
    '--fc': Spec('[Hz] cut-off', (0.0, 50_000.0)),
    '--taps': Spec('[-] FIR taps', (1, 100_000)),
    '--port': Spec('[-] TCP/UDP port (0: any free one)', (0, 65535)),
    '--priority': Spec('[-] SCHED_FIFO priority', (0, 99)),
    '--rt-priority': Spec('[-] SCHED_FIFO priority (0: none)', (0, 99)),
    **{opt: Spec('[-] ROS domain id', (0, 232))
       for opt in ('--domain', '--domain-a', '--domain-b')},
    '--domain-id': Spec('[-] ROS domain id (-1: ROS_DOMAIN_ID)', (-1, 232)),
    '--seed': Spec('[-] random seed', (0, 2**32 - 1)),
    '--workers': Spec('[-] worker processes', (1, 256)),
    **{opt: Spec('[-] count', (1, 1_000_000))
       for opt in ('--draws', '--n-fn', '--n-zeta', '--n-freq', '--n-ratio', '--n-dtm',
                   '--status-every', '--watchdog-steps', '--max-nfev', '--n-correction')},
    '--force-scale': Spec('[-] specimens the one in the lab stands for', (0.0, 1e6)),
    '--scale': Spec('[-] ground-motion scale', (0.0, 1000.0)),
    '--rate-divisor': Spec('[-] loop steps per numerical step (1: single rate)',
                           RATE_DIVISOR_RANGE),
    '--record-dt': Spec('[s] time step of a single-column record (0: not given)', (0.0, 1e3)),
}


def option_type(option: str, base, spec: Spec | None):
    """Return an argparse ``type`` that parses ``base`` and refuses a value outside ``spec``.

    A float option without a range still refuses nan and inf. The error names the
    option, the range with its unit and what the option is.
    """
    def parse(text):
        try:
            value = base(text)
        except (TypeError, ValueError):
            raise argparse.ArgumentTypeError(f'invalid {base.__name__} value: {text!r}') from None
        if isinstance(value, float) and value != value or value in (float('inf'), float('-inf')):
            raise argparse.ArgumentTypeError(f'{text!r} is not a finite number')
        if spec is not None and spec.range is not None:
            low, high = spec.range
            if not low <= value <= high:
                unit = spec.description.split(']')[0][1:] if spec.description.startswith('[') \
                    else ''
                what = spec.description.split('] ', 1)[-1]
                raise argparse.ArgumentTypeError(
                    f'{text} is outside the supported range [{_num(low)}, {_num(high)}]'
                    f'{" " + unit if unit and unit != "-" else ""} ({what})')
        return value

    parse.__name__ = base.__name__
    parse.option_range = spec  # type: ignore[attr-defined]
    return parse


def check_option_ranges(parser, ranges: dict | None = None) -> None:
    """Give every int/float option of ``parser`` and its sub-parsers a checked ``type``.

    ``ranges`` (default :data:`OPTION_RANGES`) maps an option string to its Spec.
    """
    ranges = OPTION_RANGES if ranges is None else ranges
    parsers = [parser]
    while parsers:
        current = parsers.pop()
        for action in current._actions:
            if isinstance(action, argparse._SubParsersAction):
                parsers += list(action.choices.values())
            elif action.type in (int, float):
                spec = next((ranges[o] for o in action.option_strings if o in ranges), None)
                option = action.option_strings[0] if action.option_strings else action.dest
                action.type = option_type(option, action.type, spec)
