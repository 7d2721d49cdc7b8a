"""The extension points of rths in one place: every registry, for ``rths extensions`` and the docs.

Each registry (:class:`rths_common.registry.Registry`) lives in the lowest package that
uses its names; this module, at the top, only lists them.  Two kinds of text repeat the
names and are made from the registries, never typed: ``docs/extending.md`` holds one
table per registry between ``<!-- registry: NAME -->`` and ``<!-- /registry -->``
(:func:`sync_docs`), and a params file's comment after a key that names an entry
(``specimen: valve4  # valve1 | ...``) lists the registry's names (:func:`sync_yaml`).
``rths extensions --write FILE...`` rewrites both; the drift test
(``test/test_registries.py``) fails when they differ.
"""

from pathlib import Path
import re

from rths_actuator_bridge.bridge import BACKENDS
from rths_compensator.methods import METHODS
from rths_compensator.schemes import SCHEMES
from rths_numerical.ground_motion import FORMATS
from rths_numerical.specimens import SPECIMENS

#: Registry name (as in docs/extending.md) -> registry, in the order the docs explain them.
REGISTRIES = {
    'specimens': SPECIMENS,
    'record formats': FORMATS,
    'compensator schemes': SCHEMES,
    'compensation methods': METHODS,
    'bridge backends': BACKENDS,
}

#: (node, key) of a params file whose value is a registry's name -> the registry.
KEYS = {('bridge', 'specimen'): SPECIMENS, ('bridge', 'backend'): BACKENDS,
        ('compensator', 'scheme'): SCHEMES, ('compensator', 'method'): METHODS}

_COMMENTED = re.compile(r'^(?P<head>\s+(?P<key>[a-z_]+): *\S+ *)# (?P<comment>.*)$')
_BLOCK = re.compile(r'(<!-- registry: (?P<name>[a-z ]+) -->\n)(?P<body>.*?)(<!-- /registry -->)',
                    re.S)
_SCHEMA = re.compile(r'(<!-- schema: ranges -->\n)(?P<body>.*?)(<!-- /schema -->)', re.S)


def schema_table() -> str:
    """Return docs/nodes.md's table of every ranged parameter of the three loop nodes."""
    # lazy: start-up cost: the node modules load rclpy (~0.3 s); only this table needs them
    from rths_actuator_bridge.bridge import param_schema as bridge_schema
    from rths_actuator_bridge.node import NODE_PARAMS as BRIDGE
    from rths_compensator.node import NODE_PARAMS as COMPENSATOR
    from rths_compensator.params import param_schema as compensator_schema
    from rths_numerical.node import NODE_PARAMS as NUMERICAL
    from rths_numerical.substructure import param_schema as numerical_schema

    rows = ['| node | parameter | range | what it is |', '|---|---|---|---|']
    for node, schema in (('numerical', numerical_schema(NUMERICAL)),
                         ('compensator', compensator_schema(COMPENSATOR)),
                         ('bridge', bridge_schema(BRIDGE))):
        for key, spec in schema.items():
            if spec.range is None:
                continue
            low, high = (v if isinstance(v, int) else f'{v:g}' for v in spec.range)
            kind = 'integer' if isinstance(spec.range[0], int) else 'float'
            what = spec.description + ('; one number for every actuator or a list of one '
                                       'per actuator' if spec.per_channel else '')
            rows.append(f'| {node} | `{key}` | {kind} [{low}, {high}] | {what} |')
    return '\n'.join(rows) + '\n'


def sync_docs(path, write: bool = False) -> list:
    """Return the generated tables of ``path`` that differ from their source; fix if ``write``.

    The tables: one per registry (a page that has one must have all of
    :data:`REGISTRIES`), and the parameter ranges of the loop nodes' schemas
    (``<!-- schema: ranges -->``, docs/nodes.md).
    """
    path = Path(path)
    text = path.read_text(encoding='utf-8')
    stale, seen = [], set()

    def table(match):
        name = match.group('name')
        if name not in REGISTRIES:
            raise ValueError(f'{path}: <!-- registry: {name} --> names no registry; use one of '
                             f'{", ".join(REGISTRIES)}')
        seen.add(name)
        body = REGISTRIES[name].markdown()
        if match.group('body') != body:
            stale.append(name)
        return match.group(1) + body + match.group(4)

    new = _BLOCK.sub(table, text)
    if seen:                                   # a page of registry tables has them all
        stale += [name for name in REGISTRIES if name not in seen]
    match = _SCHEMA.search(new)
    if match:
        body = schema_table()
        if match.group('body') != body:
            stale.append('schema: ranges')
        new = _SCHEMA.sub(lambda m: m.group(1) + body + m.group(3), new)
    if write and new != text:
        path.write_text(new, encoding='utf-8')
    return stale


def sync_yaml(path, write: bool = False) -> list:
    """Return the keys of :data:`KEYS` whose comment in ``path`` is not the registry's list.

    The comment after such a key must be the names joined by `` | ``; ``write`` fixes it.
    """
    path = Path(path)
    lines = path.read_text(encoding='utf-8').splitlines(keepends=True)
    stale, node = [], ''
    for i, line in enumerate(lines):
        if line[:1].isalpha():
            node = line.split(':')[0]
        match = _COMMENTED.match(line.rstrip('\n'))
        if match is None or (node, match.group('key')) not in KEYS:
            continue
        want = KEYS[node, match.group('key')].text()
        if match.group('comment') != want:
            stale.append(match.group('key'))
            lines[i] = f"{match.group('head')}# {want}\n"
    if write and stale:
        path.write_text(''.join(lines), encoding='utf-8')
    return stale


def sync(path, write: bool = False) -> list:
    """Check (and with ``write`` fix) a docs page (.md) or a params file (.yaml)."""
    return sync_docs(path, write) if str(path).endswith('.md') else sync_yaml(path, write)


def register(commands, benches):
    """Add ``rths extensions``."""
    p = commands.add_parser(
        'extensions', help='list what a lab can choose: specimens, record formats, schemes, '
                           'methods, backends',
        description='Print every extension point of rths with its names and what each is '
                    '(the registries; docs/extending.md shows how to add one).')
    p.add_argument('--write', metavar='FILE', nargs='+', default=[],
                   help='rewrite the names in FILE from the registries: the tables of a docs '
                        'page (docs/extending.md) or the comment lists of a params file '
                        '(config/bridge.yaml)')
    p.set_defaults(func=cmd_extensions)


def cmd_extensions(args) -> int:
    """``rths extensions``."""
    if args.write:
        for path in args.write:
            stale = sync(path, write=True)
            print(f'{path}: ' + (f'rewrote {", ".join(stale)}' if stale else 'up to date'))
        return 0
    for name, registry in REGISTRIES.items():
        print(f'{name} ({registry.key}):')
        width = max(len(n) for n in registry)
        for entry, summary in registry.summaries().items():
            print(f'  {entry:<{width}}  {summary}')
    return 0
