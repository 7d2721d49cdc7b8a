"""Imports sit at module level, so a module's first lines show what it depends on.

An import inside a function must say why, on the line above it (``# lazy: ...``): an
optional dependency (OpenSeesPy, foxglove, the baselines' packages), a measured start-up
cost (SciPy, matplotlib, ROS in a module that does not otherwise load them), or a command
module of ``rths``, which every command imports to build its parser (one note for the
module, ``Imports of the commands' code sit in the command functions``).

And every import of an rths package runs down the layers that docs/architecture.md draws, to a
package the importer's package.xml declares.
"""

import ast
import os
from pathlib import Path
import re

ROOT = Path(os.environ.get('RTHS_ROOT') or Path(__file__).resolve().parents[3])
COMMAND_MODULE_NOTE = "Imports of the commands' code sit in the command functions"


def _unexplained(path: Path) -> list:
    text = path.read_text(encoding='utf-8')
    lines = text.splitlines()
    tree = ast.parse(text)
    if COMMAND_MODULE_NOTE in text:
        return []
    top = {id(n) for n in tree.body}
    imports = [n for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom))]
    covered = {i for n in imports for i in range(n.lineno, n.end_lineno + 1)}
    out = []
    for node in imports:
        if id(node) in top:
            continue
        i = node.lineno - 1
        while i in covered or lines[i - 1].strip().startswith(('matplotlib.use(', 'if ')):
            i -= 1
        if not lines[i - 1].strip().startswith('# lazy:'):
            out.append(f'{path.relative_to(ROOT)}:{node.lineno}: {lines[node.lineno - 1].strip()}')
    return out


def test_every_function_level_import_says_why():
    sources = [p for p in sorted((ROOT / 'src').glob('*/*/**/*.py'))
               if 'test' not in p.relative_to(ROOT / 'src').parts[1:]]
    unexplained = [line for path in sources for line in _unexplained(path)]
    assert not unexplained, '\n'.join(unexplained)


def _layers() -> dict:
    """Package -> floor, as docs/architecture.md draws the layers (``N  rths_x  text``)."""
    text = (ROOT / 'docs' / 'architecture.md').read_text(encoding='utf-8')
    block = text.split('## Layers, bottom-up', 1)[1].split('```')[1]
    return {m.group(2): int(m.group(1))
            for m in re.finditer(r'^\s*(\d+)\s+(rths_\w+)\s', block, re.MULTILINE)}


def _rths_imports(path: Path) -> set:
    tree = ast.parse(path.read_text(encoding='utf-8'))
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.name.split('.')[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            names.add(node.module.split('.')[0])
    return {n for n in names if n.startswith('rths_')}


def test_every_import_runs_down_the_layers_and_is_declared():
    layers = _layers()
    found = sorted(p.name for p in (ROOT / 'src').iterdir() if (p / 'package.xml').exists()
                   and p.name != 'rths_msgs')
    assert sorted(layers) == found, 'docs/architecture.md: the layers name every package'
    wrong = []
    for package, floor in layers.items():
        declared = set(re.findall(r'<exec_depend>(rths_\w+)</exec_depend>',
                                  (ROOT / 'src' / package / 'package.xml').read_text()))
        for path in sorted((ROOT / 'src' / package / package).rglob('*.py')):
            for name in sorted(_rths_imports(path) - {package, 'rths_msgs'}):
                where = f'{path.relative_to(ROOT)}: imports {name}'
                if name in layers and layers[name] >= floor:
                    wrong.append(f'{where} (floor {layers[name]}), not below floor {floor}')
                if name in layers and name not in declared:
                    wrong.append(f'{where}, not an exec_depend of src/{package}/package.xml')
    assert not wrong, '\n'.join(wrong)
