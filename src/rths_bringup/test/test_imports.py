"""Imports sit at module level, so a module's first lines show what it depends on.

An import inside a function must say why, on the line above it (``# lazy: ...``): an
optional dependency (OpenSeesPy, foxglove, the baselines' packages), a measured start-up
cost (SciPy, matplotlib, ROS in a module that does not otherwise load them), or a command
module of ``rths``, which every command imports to build its parser (one note for the
module, ``Imports of the commands' code sit in the command functions``).
"""

import ast
import os
from pathlib import Path

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
