"""Fault injection for the system tests: a faulty publisher, test-only node executables, an overlay.

The production nodes take no fault parameters.  A test that needs a node to
lose, duplicate or delay its loop output runs the graph with
``rths(..., faults={node: {fault: value}})`` (:func:`rths_system_tests.rths`):
the run's environment then has an ament overlay prefix (:func:`overlay`) in
front of the workspace whose ``numerical_node``, ``compensator_node`` and
``container`` executables are this module's wrappers (every other file of
those packages is a link to the installed one).  A wrapper runs the
production entry point and, before the node spins, puts a
:class:`FaultyPublisher` around the node's loop publisher (composed: outside
the container's recording tee, so the bag sees what the graph sees), as
``ControllerEmulator(faults=...)`` does for the controller's network.

Faults (steps k > 0 with k % N == 0; 0 = off), per node ``numerical`` or
``compensator`` (or ``bridge``, its measurement; composed layout only: the
container is wrapped, the bridge's own executable is not):

* ``drop_every``: the output of step k is not published (a lost message);
* ``duplicate_every``: it is published twice;
* ``delay_every`` with ``delay_ms``: the node sleeps ``delay_ms`` before publishing
  it (a delay burst: the step path stalls).
"""

import json
import os
from pathlib import Path
import sys
import tempfile
import time

#: The faults a node can be given, with their off value.
FAULTS = {'drop_every': 0, 'duplicate_every': 0, 'delay_every': 0, 'delay_ms': 0.0}
#: Nodes whose loop output can be made faulty.
NODES = ('numerical', 'compensator', 'bridge')
#: package -> (executable, module with main(argv, prepare), the node it runs or None: composed)
WRAPPED = {'rths_numerical': ('numerical_node', 'rths_numerical.node', 'numerical'),
           'rths_compensator': ('compensator_node', 'rths_compensator.node', 'compensator'),
           'rths_bringup': ('container', 'rths_bringup.container', None)}


def check_faults(faults: dict) -> dict:
    """Return ``{node: {fault: value}}`` with every fault set; ValueError naming a bad key."""
    out = {}
    for node, given in (faults or {}).items():
        if node not in NODES:
            raise ValueError(f'faults: node {node!r}: use one of {NODES}')
        unknown = set(given) - set(FAULTS)
        if unknown:
            raise ValueError(f'faults of {node}: unknown {sorted(unknown)}; use {sorted(FAULTS)}')
        out[node] = dict(FAULTS, **given)
    return out


class FaultyPublisher:
    """Wraps a loop publisher: drops, duplicates or delays the messages of chosen steps."""

    def __init__(self, publisher, drop_every=0, duplicate_every=0, delay_every=0, delay_ms=0.0):
        self.publisher = publisher
        self.drop_every = int(drop_every)
        self.duplicate_every = int(duplicate_every)
        self.delay_every = int(delay_every)
        self.delay_s = float(delay_ms) * 1e-3
        self.counts = {'dropped': 0, 'duplicated': 0, 'delayed': 0}

    @staticmethod
    def step_of(msg) -> int:
        """Return the step of a loop message (typed, or CDR bytes)."""
        if isinstance(msg, (bytes, bytearray)):
            from rths_common import cdr
            return int(cdr.unpack_step_arrays(bytes(msg))[1])
        return int(msg.step)

    def publish(self, msg):
        """Publish ``msg`` with the faults of its step."""
        step = self.step_of(msg)

        def due(every):
            return every > 0 and step > 0 and step % every == 0

        if due(self.delay_every):
            self.counts['delayed'] += 1
            time.sleep(self.delay_s)
        if due(self.drop_every):
            self.counts['dropped'] += 1
            return
        self.publisher.publish(msg)
        if due(self.duplicate_every):
            self.counts['duplicated'] += 1
            self.publisher.publish(msg)

    def __getattr__(self, name):
        """Everything else is the wrapped publisher's."""
        return getattr(self.publisher, name)


def inject(shells: dict, faults: dict):
    """Wrap the loop publisher (``pub``) of each shell named in ``faults``."""
    for name, given in check_faults(faults).items():
        shell = shells.get(name)
        if shell is not None:
            shell.pub = FaultyPublisher(shell.pub, **given)
            shell.node.get_logger().warning(f'test fault injection: {given}')


def run(package: str, faults: dict) -> int:
    """Run the production entry point of ``package``'s wrapped executable with ``faults``."""
    import importlib

    _, module, node = WRAPPED[package]
    main = importlib.import_module(module).main
    if node is None:   # the composed container: its three shells
        return main(prepare=lambda container: inject(container.shells, faults))
    return main(prepare=lambda shell: inject({node: shell}, faults))


def _link_package(root: Path, package: str, faults: dict):
    from ament_index_python.packages import get_package_prefix

    real = Path(get_package_prefix(package))
    marker = root / 'share' / 'ament_index' / 'resource_index' / 'packages' / package
    marker.parent.mkdir(parents=True, exist_ok=True)
    marker.touch()
    (root / 'share' / package).symlink_to(real / 'share' / package)
    lib = root / 'lib' / package
    lib.mkdir(parents=True)
    exe = WRAPPED[package][0]
    for path in (real / 'lib' / package).iterdir():
        if path.name != exe:
            (lib / path.name).symlink_to(path)
    script = lib / exe
    script.write_text(f'#!{sys.executable}\n"""Test-only: {exe} with injected faults."""\n'
                      'import sys\n'
                      'from rths_system_tests.faults import run\n'
                      f'sys.exit(run({package!r}, {json.dumps(faults)}))\n')
    script.chmod(0o755)


def overlay(faults: dict, directory=None) -> Path:
    """Build an ament prefix whose node executables inject ``faults``; return its path."""
    faults = check_faults(faults)
    root = Path(directory or tempfile.mkdtemp(prefix='rths-faults-'))
    packages = ['rths_bringup'] + [p for p, (_, _, node) in WRAPPED.items() if node in faults]
    for package in packages:
        _link_package(root, package, faults)
    return root


def overlay_env(env: dict, faults: dict) -> dict:
    """``env`` with an overlay for ``faults`` in front of ``AMENT_PREFIX_PATH``."""
    root = overlay(faults)
    return dict(env, AMENT_PREFIX_PATH=os.pathsep.join(
        [str(root)] + [p for p in env.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]))
