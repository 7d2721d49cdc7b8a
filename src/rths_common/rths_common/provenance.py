"""Provenance of a run, kept in its bag's run information: what made it, where, from which files.

The run information (:mod:`rths_common.runinfo`) already holds every node
parameter of the run with its overrides applied (except the long arrays,
``runinfo.SKIP``), and ``/rths/run_inputs`` the model and the processed ground
motion.  :func:`collect` adds what they lack, as ``provenance.*`` keys:

* ``provenance.rths_version`` (the installed rths packages), ``provenance.git_commit``
  (``-dirty`` appended when the checkout has uncommitted changes; empty when
  rths does not run from a git checkout), ``provenance.host``,
  ``provenance.platform``, ``provenance.python``, ``provenance.ros_distro``,
  ``provenance.recorded_utc``, ``provenance.config_dir``;
* the text of the params files and of the files they name that the other
  records do not carry: the compensator's taps (``compensator.yaml``), the
  plant it was designed for (its ``provenance.plant``) and an identified plant the
  bridge emulates (its ``actuator_model``), as ``provenance.file.NAME`` with
  ``provenance.sha256.NAME`` beside it (a file over MAX_FILE_BYTES by its digest only).

:func:`of_run_info` reads them back.
"""

import datetime
import hashlib
from importlib import metadata
import os
from pathlib import Path
import platform
import socket
import subprocess

#: Prefix of the provenance keys in the run information.
PREFIX = 'provenance.'
#: The params files of a run's config directory.
PARAMS_FILES = ('bridge.yaml', 'compensator.yaml', 'numerical.yaml')
#: A file larger than this [bytes] is kept by its SHA-256 only.
MAX_FILE_BYTES = 256 * 1024


def rths_version() -> str:
    """Return the version of the installed rths packages (rths_common's), '' if not installed."""
    try:
        return metadata.version('rths_common')
    except metadata.PackageNotFoundError:
        return ''


def git_commit(root=None) -> str:
    """Return the commit of the rths checkout (``-dirty`` if changed), '' without one."""
    root = Path(root or os.environ.get('RTHS_ROOT') or Path(__file__).resolve().parent)
    try:
        head = subprocess.run(['git', '-C', str(root), 'rev-parse', 'HEAD'], capture_output=True,
                              text=True, timeout=5)
        if head.returncode:
            return ''
        dirty = subprocess.run(['git', '-C', str(root), 'status', '--porcelain',
                                '--untracked-files=no'], capture_output=True, text=True,
                               timeout=5)
    except (OSError, subprocess.SubprocessError):
        return ''
    return head.stdout.strip() + ('-dirty' if dirty.stdout.strip() else '')


def named_files(config_dir) -> list:
    """Return the files of a config directory a run reads: its params files and the plants named.

    A missing or unreadable params file is skipped (the launcher refuses it itself).
    """
    # lazy: runinfo imports yaml, which the rest of this module does not need
    from rths_common import runinfo

    config_dir = Path(config_dir)
    files = [config_dir / name for name in PARAMS_FILES if (config_dir / name).is_file()]
    named = []
    try:
        comp = runinfo.load_params(config_dir / 'compensator.yaml', 'compensator')
        named.append((comp.get('provenance') or {}).get('plant'))
    except (OSError, ValueError, AttributeError):
        pass
    try:
        named.append(runinfo.load_params(config_dir / 'bridge.yaml', 'bridge')
                     .get('actuator_model'))
    except (OSError, ValueError):
        pass
    for name in named:
        if isinstance(name, str) and name.endswith(('.yaml', '.yml', '.json')):
            path = (config_dir / name).resolve()
            if path.is_file() and path not in files:
                files.append(path)
    return files


def collect(config_dir=None) -> dict:
    """Return the ``provenance.*`` run information of a run (module doc); values are strings."""
    info = {
        f'{PREFIX}rths_version': rths_version(),
        f'{PREFIX}git_commit': git_commit(),
        f'{PREFIX}host': socket.gethostname(),
        f'{PREFIX}platform': platform.platform(),
        f'{PREFIX}python': platform.python_version(),
        f'{PREFIX}ros_distro': os.environ.get('ROS_DISTRO', ''),
        f'{PREFIX}recorded_utc': datetime.datetime.now(datetime.timezone.utc)
        .isoformat(timespec='seconds'),
    }
    if config_dir:
        info[f'{PREFIX}config_dir'] = str(Path(config_dir).resolve())
        for path in named_files(config_dir):
            try:
                data = path.read_bytes()
            except OSError:
                continue
            info[f'{PREFIX}sha256.{path.name}'] = hashlib.sha256(data).hexdigest()
            if len(data) <= MAX_FILE_BYTES:
                info[f'{PREFIX}file.{path.name}'] = data.decode('utf-8', errors='replace')
    return info


def of_run_info(info: dict) -> dict:
    """Return ``{'rths_version': ..., 'files': {name: {'sha256', 'text'}}, ...}`` of run info."""
    out: dict = {'files': {}}
    for key, value in info.items():
        if not key.startswith(PREFIX):
            continue
        name = key[len(PREFIX):]
        for kind in ('file.', 'sha256.'):
            if name.startswith(kind):
                entry = out['files'].setdefault(name[len(kind):], {})
                entry['text' if kind == 'file.' else 'sha256'] = str(value)
                break
        else:
            out[name] = str(value)
    return out
