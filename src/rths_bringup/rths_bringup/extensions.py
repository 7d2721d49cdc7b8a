"""The extension points of rths in one place: every registry, for ``rths extensions`` and the docs.

Each registry (:class:`rths_common.registry.Registry`) lives in the lowest package that
uses its names; this module, at the top, only lists them.  ``docs/extending.md`` holds
one table per registry between ``<!-- registry: NAME -->`` and ``<!-- /registry -->``;
:func:`sync_docs` rewrites those tables from the registries (``rths extensions
--write-docs``) and the drift test (``test/test_registries.py``) fails when they differ.
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

_BLOCK = re.compile(r'(<!-- registry: (?P<name>[a-z ]+) -->\n)(?P<body>.*?)(<!-- /registry -->)',
                    re.S)


def sync_docs(path, write: bool = False) -> list:
    """Return the registries whose table in ``path`` differs from the registry; fix if ``write``.

    A registry of :data:`REGISTRIES` without a block in the file counts as differing.
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
    stale += [name for name in REGISTRIES if name not in seen]
    if write and new != text:
        path.write_text(new, encoding='utf-8')
    return stale


def register(commands, benches):
    """Add ``rths extensions``."""
    p = commands.add_parser(
        'extensions', help='list what a lab can choose: specimens, record formats, schemes, '
                           'methods, backends',
        description='Print every extension point of rths with its names and what each is '
                    '(the registries; docs/extending.md shows how to add one).')
    p.add_argument('--write-docs', metavar='FILE', default=None,
                   help='rewrite the registry tables of FILE (docs/extending.md) from the '
                        'registries')
    p.set_defaults(func=cmd_extensions)


def cmd_extensions(args) -> int:
    """``rths extensions``."""
    if args.write_docs:
        stale = sync_docs(args.write_docs, write=True)
        print(f'{args.write_docs}: ' + (f'rewrote {", ".join(stale)}' if stale else 'up to date'))
        return 0
    for name, registry in REGISTRIES.items():
        print(f'{name} ({registry.key}):')
        width = max(len(n) for n in registry)
        for entry, summary in registry.summaries().items():
            print(f'  {entry:<{width}}  {summary}')
    return 0
