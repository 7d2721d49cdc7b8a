"""Drift test over every registry: schema choices, argparse choices, YAML comments, docs tables.

The names of the specimens, record formats, compensator schemes, compensation methods and
bridge backends are typed once, in their registry (rths_bringup.extensions.REGISTRIES).
Everything that repeats them is made from the registry; this test fails when any of them
differs, and when a specimen, scheme or format name is written as a string in more than two
non-test source files (its registry and its module).
"""

import ast
import os
from pathlib import Path

import pytest

from rths_actuator_bridge.bridge import BACKENDS
from rths_bringup.cli import build_parser
from rths_bringup.extensions import KEYS, REGISTRIES, sync
from rths_compensator.methods import METHODS
from rths_compensator.schemes import SCHEMES, designed
from rths_numerical.ground_motion import FORMATS
from rths_numerical.specimens import SPECIMENS

ROOT = Path(os.environ.get('RTHS_ROOT') or Path(__file__).resolve().parents[3])

#: Words that are a registry name and also an ordinary word of another concept, with the
#: files where they mean that other concept (None: everywhere).  'none' is the word for
#: nothing in several places (the bare-table specimen, the ground-motion record, the
#: discrepancy workflow's answer), so its count says nothing about the specimen.
SHARED_WORDS = {
    'none': None,
    # the unit millimetre
    'mm': {'rths_common/rths_common/columns.py', 'rths_bringup/rths_bringup/preflight.py',
           'rths_common/rths_common/rig.py'},
}
#: Benchmarks and studies reproduce named published cases (the seed's comparison study,
#: the RTHS benchmark's controllers, a study's configurations); they are not where a name
#: chooses behaviour.
BENCHMARKS = ('rths_compensator/rths_compensator/bench.py', 'rths_bench/', 'rths_study/')


def _subparsers(parser):
    return next(a for a in parser._actions if a.__class__.__name__ == '_SubParsersAction').choices


def _option(parser, flag):
    return next(a for a in parser._actions if flag in a.option_strings)


def test_the_schema_allows_exactly_the_registered_names():
    from rths_actuator_bridge.bridge import param_schema as bridge_schema
    from rths_actuator_bridge.node import NODE_PARAMS as BRIDGE
    from rths_compensator.node import NODE_PARAMS as COMPENSATOR
    from rths_compensator.params import param_schema as compensator_schema

    schemas = {'bridge': bridge_schema(BRIDGE), 'compensator': compensator_schema(COMPENSATOR)}
    for (node, key), registry in KEYS.items():
        assert schemas[node][key].choices == registry.names(), (node, key)


def test_command_line_choices_are_the_registries():
    commands = _subparsers(build_parser())
    run = commands['run']
    assert tuple(_option(run, '--specimen').choices) == SPECIMENS.names()
    assert tuple(_option(run, '--scheme').choices) == designed()
    assert tuple(_option(run, '--adaptive').choices) == METHODS.names()
    assert tuple(_option(commands['design'], '--scheme').choices) == designed()
    emulator = commands['controller-emulator']
    assert tuple(_option(emulator, '--specimen').choices) == SPECIMENS.names()


@pytest.mark.parametrize('path', ['docs/extending.md', 'docs/nodes.md', 'config/bridge.yaml',
                                  'config/compensator.yaml', 'config/numerical.yaml'])
def test_docs_tables_and_yaml_comments_are_the_registries(path):
    stale = sync(ROOT / path)
    assert not stale, (f'{path}: {", ".join(stale)} differ from the registries; run '
                       f'rths extensions --write {path}')


def test_the_record_comment_names_every_format_ending():
    line = next(x for x in (ROOT / 'config' / 'numerical.yaml').read_text().splitlines()
                if x.strip().startswith('record:'))
    for entry in FORMATS.values():
        for ending in entry.suffixes:
            assert ending in line.lower(), ending


def test_each_name_is_written_in_at_most_two_source_files():
    sources = [p for p in (ROOT / 'src').glob('*/*/**/*.py')
               if '/test/' not in str(p) and p.parent.name != 'test']
    strings = {}
    for path in sources:
        rel = str(path.relative_to(ROOT / 'src'))
        if rel.startswith(BENCHMARKS):
            continue
        tree = ast.parse(path.read_text(encoding='utf-8'))
        strings[rel] = {n.value for n in ast.walk(tree)
                        if isinstance(n, ast.Constant) and isinstance(n.value, str)}
    too_many = {}
    for registry in (SPECIMENS, SCHEMES, FORMATS):
        for name in registry:
            if name in SHARED_WORDS and SHARED_WORDS[name] is None:
                continue
            files = sorted(f for f, values in strings.items()
                           if name in values and f not in SHARED_WORDS.get(name, ()))
            if len(files) > 2:
                too_many[name] = files
    assert not too_many, too_many


def test_every_registry_is_listed_and_described():
    listed = [id(r) for r in REGISTRIES.values()]
    assert all(id(r) in listed for r in (SPECIMENS, FORMATS, SCHEMES, METHODS, BACKENDS))
    for registry in REGISTRIES.values():
        assert all(s.strip() for s in registry.summaries().values())
