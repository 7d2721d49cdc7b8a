"""Reading the YAML files a lab writes (params files, models, plants): exactly, or refused.

Plain ``yaml.safe_load`` takes the last of two equal keys without a word (a
``stroke_m`` given twice in bridge.yaml runs on the second) and raises a
``YAMLError`` that is no ``ValueError``, so callers that catch bad input let
it through as a traceback.  :func:`load` and :func:`loads` refuse a key given
twice in one mapping and turn every YAML error into a one-line ``ValueError``
naming the file, the line and the fix.
"""

from pathlib import Path

import yaml

#: libyaml's parser where PyYAML has it (~12x faster: compensator.yaml 62 -> 5 ms).
_Base = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)


class _Loader(_Base):  # type: ignore[misc,valid-type]
    """SafeLoader that refuses a key given twice in one mapping."""


def _mapping(loader, node, deep=False):
    seen: dict = {}
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=True)
        line = key_node.start_mark.line + 1
        try:
            first = seen.get(key)
        except TypeError:                     # an unhashable key: the base class says so
            break
        if first is not None:                 # also on one line: {a: 1, a: 2}
            where = f'line {line}' if first == line else f'lines {first} and {line}'
            raise yaml.constructor.ConstructorError(
                None, None, f'key {key!r} is given twice ({where}); keep one',
                key_node.start_mark)
        seen[key] = line
    return loader.construct_mapping(node, deep)


_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _mapping)


def loads(text: str, where) -> object:
    """Parse YAML ``text`` read from ``where``; ValueError names ``where``, the line and the fix."""
    try:
        return yaml.load(text, Loader=_Loader)   # noqa: S506 (a SafeLoader)
    except yaml.YAMLError as err:
        raise ValueError(f'{where}: {describe(err)}') from None


def load(path) -> object:
    """Parse the YAML file ``path`` (:func:`loads`); OSError if it cannot be read."""
    path = Path(path)
    try:
        text = path.read_text(encoding='utf-8')
    except (OSError, UnicodeDecodeError) as err:
        raise OSError(f'{path}: cannot read the file ({getattr(err, "strerror", err)})') from None
    return loads(text, path)


def describe(err: yaml.YAMLError) -> str:
    """Return one line for a YAML error: where in the file, what, and the fix."""
    if isinstance(err, yaml.reader.ReaderError):   # a byte or character YAML does not allow
        return (f'not valid YAML at character {err.position + 1}: {err.reason}; '
                'write the file as UTF-8 text without control characters')
    mark = getattr(err, 'problem_mark', None)
    problem = getattr(err, 'problem', None) or str(err)
    if problem.startswith('key ') and 'given twice' in problem:
        return problem
    where = f' at line {mark.line + 1}, column {mark.column + 1}' if mark is not None else ''
    return f'not valid YAML{where}: {problem}; fix the syntax'
