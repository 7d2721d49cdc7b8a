"""Run information: the parameters of a run, kept in its bag so the review needs only the bag.

The recorder stores every parameter it is given as the bag's run information
(rosbag2 ``custom_data`` and a side file, :mod:`rths_common.bagio`).  Keys are
``fs_hz``, ``mode``, ``kind`` (``identification`` or ``rths``) and the
numerical and bridge parameters prefixed with ``numerical.`` / ``bridge.``.
Values are strings in the bag; :func:`section` parses them back with YAML.
"""

import datetime
from pathlib import Path
from typing import Any

import yaml

from rths_common import yamlfile

#: Parameters that are not worth keeping in run information (long arrays, node plumbing).
SKIP = {'taps', 'denominator', 'history_out', 'executor', 'wait_for_subscribers',
        'wait_for_stop_readers'}


def load_params(path, node: str) -> dict:
    """Return the ``ros__parameters`` of ``node`` in a params file (ValueError names the file)."""
    path = Path(path)
    if not path.is_file():
        raise OSError(f'params file {path} not found')
    doc: Any = yamlfile.load(path)
    try:
        params = doc[node]['ros__parameters']
    except (TypeError, KeyError):
        raise ValueError(f"{path}: expected '{node}:' then 'ros__parameters:' at the top") from None
    if not isinstance(params, dict):
        raise ValueError(f'{path}: {node}.ros__parameters must be a mapping')
    return dict(params)


def write_params(path, node: str, params: dict) -> Path:
    """Write a ROS 2 params file for ``node`` (floats stay floats, lists stay flow-style)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = yaml.safe_dump({node: {'ros__parameters': params}}, default_flow_style=None,
                          sort_keys=False, width=100)
    path.write_text(text)
    return path


def flatten(kind: str, fs_hz: float, mode: str, sections: dict) -> dict:
    """Run information for the recorder: ``{'numerical.model': 'sdof', ...}`` as strings.

    A nested mapping (the compensator's ``provenance``) becomes dotted keys, as ROS
    names it: ``compensator.provenance.plant``.
    """
    info = {'kind': kind, 'fs_hz': repr(float(fs_hz)), 'mode': mode}
    for name, params in sections.items():
        for key, value in params.items():
            if key not in SKIP:
                _flatten_into(info, f'{name}.{key}', value)
    return info


def _flatten_into(info: dict, name: str, value) -> None:
    if isinstance(value, dict):
        for key, item in value.items():
            _flatten_into(info, f'{name}.{key}', item)
        return
    text = yaml.safe_dump(value, default_flow_style=True).strip()
    info[name] = text.removesuffix('\n...')  # scalar document end


def section(info: dict, name: str) -> dict:
    """Parameters of one node back from run information (values parsed with YAML)."""
    prefix = f'{name}.'
    out = {}
    for key, value in info.items():
        if key.startswith(prefix):
            value = yaml.safe_load(value) if isinstance(value, str) else value
            if isinstance(value, (datetime.date, datetime.datetime)):
                value = value.isoformat()  # YAML reads ISO times as dates; keep them text
            out[key[len(prefix):]] = value
    return out
