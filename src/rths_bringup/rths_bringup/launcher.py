"""Bring up the rths node graph, composed in one process or one OS process per node.

Two layouts (``layout``):

* ``processes``: the recorder (if a bag is requested), the actuator bridge,
  the compensator and the numerical node, each its own process as ``ros2 run``
  would start it, with ``--ros-args --params-file`` from the config directory;
  the way to spread the nodes over hosts (``node_env``/``node_prefix``);
* ``composed``: the three loop nodes in one process on one executor
  (:mod:`rths_bringup.container`), each with its own params file and the
  overrides in a params file of its own; with a bag, the container copies what
  it publishes into a pipe the recorder reads (:mod:`rths_common.tee`), so
  nothing is lost.  The container's log lines are prefixed with the name of
  the node that logged them; when it ends early the launcher names the node
  that ended it (the bridge's safety stop: ``node bridge died (exit code 3:
  safety stop) in the container``).

The default (None) is ``composed`` for a realtime run on one host and
``processes`` in lock-step (deterministic either way: the fault tests kill one
node process) and whenever ``node_env``/``node_prefix`` place nodes apart.

The launcher streams the output of every process prefixed with the node name
and supervises them:

* the numerical node owns the run: when it exits with code 0 the run is over,
  and the others are stopped in loop order (SIGINT), the recorder last so it
  keeps every message;
* if any node dies first (non-zero exit or a signal such as SIGKILL), the
  launcher stops the rest and exits non-zero, naming the node;
* Ctrl-C / SIGTERM to the launcher stops every node cleanly;
* if the launcher itself dies (even by SIGKILL) every child follows it
  (:mod:`rths_common.lifeline`): the bridge ramps the actuator to its safe
  position within ``launcher_loss_stop_s`` and exits, the recorder records that
  and closes the bag, the numerical node and the compensator stop;
* if the recorder died, the bag is reindexed so it stays readable;
* if the numerical node or the compensator died, the launcher first lets the
  bridge's watchdog bring the plant to the safe state (hold, ramp, STOPPED)
  and reports the time it took against :meth:`Launcher.safe_stop_bound_s`;
  if the bridge died, it states the plant's state (simulated: it died with
  the process) or deactivates the UDP servo controller;
* every params file is checked before anything starts
  (:mod:`rths_bringup.preflight`): a bad one raises ValueError naming file,
  field and fix, and nothing is written;
* ``node_env`` / ``node_prefix`` give a node its own environment (ROS domain,
  discovery) and command prefix (``ip netns exec HOST``): distributed runs;
* every run is isolated (:mod:`rths_bringup.isolation`): it holds its ROS domain
  (``ROS_DOMAIN_ID``, else a free one) while it runs, refusing to start when
  another run holds it, and gives every node a fresh run identity (``run_id``).

Timing mode: ``mode`` None (the default) takes the numerical node's ``mode``
from the config (or its override), so the recorder subscribes with matching
QoS; an explicit ``mode`` is also passed to every node as an override, and a
node whose file gives none runs in the run's mode.  Nodes whose modes still
differ are refused by the pre-flight check (``preflight.check_modes``).
The numerical node logs ``progress: step K of N`` every simulated second; the
launcher turns those lines into the run's progress (:mod:`rths_common.progress`,
on stderr, labelled ``progress_label``) instead of echoing them.
While the graph runs, the CPU time of every child is sampled
(:attr:`Launcher.cpu_samples`, from /proc) for ``rths bench loop``.

``ros2 launch`` is not available in this environment; this module is the
project's equivalent and needs only the built workspace (``source env.sh``).
"""

from dataclasses import dataclass, field
import os
from pathlib import Path
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time

import yaml

from rths_bringup import isolation
from rths_bringup.preflight import check_config
from rths_common import lifeline, yamlfile
from rths_common.bagio import reindex
from rths_common.progress import Progress

#: (name, package, executable, params file) in start order; the recorder comes first.
NODES = (
    ('bridge', 'rths_actuator_bridge', 'bridge_node', 'bridge.yaml'),
    ('compensator', 'rths_compensator', 'compensator_node', 'compensator.yaml'),
    ('numerical', 'rths_numerical', 'numerical_node', 'numerical.yaml'),
)
RECORDER = ('recorder', 'rths_bringup', 'recorder', None)
CONTAINER = ('container', 'rths_bringup', 'container', None)
OWNER = 'numerical'  # the node whose clean exit ends the run (processes layout)
LAYOUTS = ('composed', 'processes')
#: Seconds the recorder gets to empty the composed layout's recording pipe after SIGINT.
RECORDER_GRACE_S = 60.0
#: A log line of a ROS node: ``[LEVEL] [stamp] [logger]: text`` (the logger names the node).
_LOGGER = re.compile(r'^\[\w+\] \[[\d.]+\] \[(\w+)')
#: The numerical node's progress log line: steps done and the run's steps.
_PROGRESS = re.compile(r'\]: progress: step (\d+) of (\d+) ')


def executable(package: str, name: str) -> Path:
    """Path of an installed node executable, found through the ament index like ``ros2 run``."""
    # lazy: ROS: the ROS-free parts of this module import without it
    from ament_index_python.packages import PackageNotFoundError, get_package_prefix

    try:
        path = Path(get_package_prefix(package)) / 'lib' / package / name
    except PackageNotFoundError:
        raise OSError(f"package {package!r} is not installed; run 'make setup' and "
                      "'source env.sh'") from None
    if not os.access(path, os.X_OK):
        raise OSError(f'{path} is missing or not executable; rebuild with make setup')
    return path


def config_param(config_dir: Path, overrides: dict, key: str, default, node: str = OWNER):
    """Return ``node``'s ``key``: its override, else its params file, else ``default``."""
    value = overrides.get(node, {}).get(key)
    if value not in (None, ''):
        return value
    path = Path(config_dir) / f'{node}.yaml'
    try:
        data = yamlfile.load(path) or {}
    except (OSError, ValueError):
        return default              # the pre-flight check names the problem
    if not isinstance(data, dict):
        return default
    for section in data.values():
        if isinstance(section, dict) and key in (section.get('ros__parameters') or {}):
            return section['ros__parameters'][key]
    return default


def config_mode(config_dir: Path, overrides: dict) -> str:
    """Return a run's timing mode: the numerical override, else its params file, else lockstep."""
    return str(config_param(config_dir, overrides, 'mode', 'lockstep'))


def loop_rate_override(config_dir: Path, overrides: dict) -> None:
    """Give the compensator the loop rate (``loop_fs_hz``): it refuses taps for another rate.

    The loop rate is the numerical node's ``fs_hz``; a value that is not a
    number is left to the pre-flight check, which names it.
    """
    try:
        fs = float(config_param(config_dir, overrides, 'fs_hz', 1024.0))
    except (TypeError, ValueError):
        return
    overrides.setdefault('compensator', {}).setdefault('loop_fs_hz', fs)


_CLK_TCK = os.sysconf('SC_CLK_TCK')


def cpu_seconds(pid: int):
    """User + system CPU seconds of process ``pid`` (all its threads), None if it is gone."""
    try:
        with open(f'/proc/{pid}/stat', 'rb') as f:
            fields = f.read().rsplit(b')', 1)[1].split()
    except (OSError, IndexError):
        return None
    return (int(fields[11]) + int(fields[12])) / _CLK_TCK


@dataclass
class Child:
    """One supervised node process."""

    name: str
    argv: list
    proc: subprocess.Popen = None
    reader: threading.Thread = None
    stopping: bool = False
    lines: list = field(default_factory=list)

    @property
    def returncode(self):
        """Return the process's exit code, None while it runs."""
        return self.proc.poll()


#: Exit codes of the rths nodes that mean something specific.
EXIT_MEANINGS = {2: 'bad parameters or input', 3: 'safety stop'}


def describe_exit(code: int) -> str:
    """Human description of a Popen return code."""
    if code is None:
        return 'running'
    if code in EXIT_MEANINGS:
        return f'exit code {code}: {EXIT_MEANINGS[code]}'
    if code < 0:
        try:
            return f'killed by {signal.Signals(-code).name}'
        except ValueError:
            return f'killed by signal {-code}'
    return f'exit code {code}'


class Launcher:
    """Start, watch and stop the node processes of one run."""

    def __init__(self, config_dir, bag=None, overrides=None, mode=None, out=sys.stdout,
                 timeout_s=None, cpu_sample_s: float = 0.25, preflight: bool = True,
                 node_env: dict = None, node_prefix: dict = None, layout: str = None,
                 progress_label: str = 'run'):
        self.config_dir = Path(config_dir)
        #: {node: {VAR: value}} environment per node (e.g. its ROS_DOMAIN_ID), and
        #: {node: [argv prefix]} (e.g. ['ip', 'netns', 'exec', 'lab1']): distributed runs
        self.node_env = node_env or {}
        self.node_prefix = node_prefix or {}
        self.preflight = preflight
        self.bag = Path(bag) if bag else None
        self.overrides = overrides or {}
        if mode is not None:
            for name, *_ in NODES:
                self.overrides.setdefault(name, {})['mode'] = mode
        self.mode = mode or config_mode(self.config_dir, self.overrides)
        for name, *_ in NODES:      # a node whose file gives no mode runs in the run's mode
            if config_param(self.config_dir, self.overrides, 'mode', None, name) is None:
                self.overrides.setdefault(name, {})['mode'] = self.mode
        loop_rate_override(self.config_dir, self.overrides)
        if layout is None:
            layout = ('composed' if self.mode == 'realtime' and not self.node_env
                      and not self.node_prefix else 'processes')
        if layout not in LAYOUTS:
            raise ValueError(f'layout {layout!r}: use composed or processes')
        if layout == 'composed' and (self.node_env or self.node_prefix):
            raise ValueError('the composed layout runs the nodes in one process on one host; '
                             'use layout processes to place nodes apart')
        self.layout = layout
        self.owner = 'container' if layout == 'composed' else OWNER
        self._tmp = None
        self.cpu_sample_s = cpu_sample_s
        #: [(wall time ns, {node: CPU seconds so far})], sampled while the graph runs
        self.cpu_samples = []
        self.out = out
        self.timeout_s = timeout_s
        self.children = []
        self._print_lock = threading.Lock()
        self._signal = None
        self.progress_label = progress_label
        self.progress = None        # rths_common.progress.Progress, from the first progress line
        self._progress_over = False

    def say(self, text: str, name: str = 'launch'):
        """Print ``text`` as a line of ``name`` (one line at a time)."""
        with self._print_lock:
            if self.progress is None:
                print(f'[{name}] {text}', file=self.out, flush=True)
                return
            with self.progress.hidden():
                print(f'[{name}] {text}', file=self.out, flush=True)

    def _progress_done(self):
        """Count every step once the run finished (the node logs whole seconds only)."""
        with self._print_lock:
            if self.progress is not None:
                if self.progress.done < self.progress.total:
                    self.progress.update(self.progress.total)
                self.progress.close()
            self.progress = None
            self._progress_over = True      # late progress lines are dropped

    def _on_progress(self, line: str) -> bool:
        """Return True if ``line`` is the numerical node's progress line (and count it).

        The progress starts when the numerical node publishes step 0 (``graph connected``).
        """
        match = _PROGRESS.search(line)
        if match is None and 'graph connected' not in line:
            return False
        with self._print_lock:
            if self._progress_over:
                return match is not None
            if self.progress is None:
                self.progress = Progress(0, self.progress_label, 'steps')
            if match is not None:
                self.progress.update(int(match.group(1)), int(match.group(2)))
        return match is not None

    def _argv(self, name, package, exe, params_file):
        argv = [str(executable(package, exe)), '--ros-args', '-r', f'__node:={name}']
        if params_file:
            path = self.config_dir / params_file
            if not path.is_file():
                raise OSError(f'params file {path} not found; give --config a directory '
                              f'holding {", ".join(n[3] for n in NODES)}')
            argv += ['--params-file', str(path)]
        for key, value in self.overrides.get(name, {}).items():
            argv += ['-p', f'{key}:={value}']
        return argv

    def _container_argv(self, tee_fd: int) -> list:
        """Build the container's argv: each node's params file, then one with its overrides."""
        self._tmp = Path(tempfile.mkdtemp(prefix='rths-container-'))
        argv = [str(executable(*CONTAINER[1:3]))]
        if tee_fd >= 0:
            argv += ['--tee-fd', str(tee_fd)]
        argv += ['--ros-args']
        for name, _, _, params_file in NODES:
            path = self.config_dir / params_file
            if not path.is_file():
                raise OSError(f'params file {path} not found; give --config a directory '
                              f'holding {", ".join(n[3] for n in NODES)}')
            argv += ['--params-file', str(path)]
            over = self.overrides.get(name)
            if over:
                extra = self._tmp / f'{name}_overrides.yaml'
                extra.write_text(yaml.safe_dump({name: {'ros__parameters': dict(over)}}))
                argv += ['--params-file', str(extra)]
        return argv

    def _stream(self, child: Child):
        for raw in child.proc.stdout:
            line = raw.rstrip('\n')
            child.lines.append(line)
            del child.lines[:-200]
            name = child.name
            if name == 'container':   # prefix each line with the node that logged it
                match = _LOGGER.match(line)
                if match and match.group(1) in {n[0] for n in NODES}:
                    name = match.group(1)
            if name == OWNER and self._on_progress(line):
                continue
            self.say(line, name)

    def culprit(self, child: Child) -> str:
        """Name the node that ended the run early (composed: from the container's exit code)."""
        if child.name != 'container':
            return child.name
        return {3: 'bridge', 1: 'numerical'}.get(child.returncode, 'container')

    def _spawn(self, name, argv, pass_fds=()):
        child = Child(name, argv)
        env = dict(os.environ, PYTHONUNBUFFERED='1', RCUTILS_COLORIZED_OUTPUT='0',
                   **lifeline.launcher_env(), **self.node_env.get(name, {}))
        argv = list(self.node_prefix.get(name, [])) + list(argv)
        child.proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                      text=True, env=env, start_new_session=True,
                                      pass_fds=tuple(pass_fds))
        child.reader = threading.Thread(target=self._stream, args=(child,), daemon=True)
        child.reader.start()
        self.children.append(child)
        self.say(f'started {name} (pid {child.proc.pid})')
        return child

    def _on_signal(self, signum, _frame):
        self._signal = signum

    def stop(self, child: Child, grace_s: float = 5.0):
        """SIGINT, then SIGTERM, then SIGKILL until ``child`` is gone."""
        if child.returncode is not None:
            return
        if child.name == 'recorder' and self.layout == 'composed':
            grace_s = RECORDER_GRACE_S   # it empties the recording pipe first
        child.stopping = True
        for sig, wait in ((signal.SIGINT, grace_s), (signal.SIGTERM, 2.0), (signal.SIGKILL, 2.0)):
            try:
                os.killpg(child.proc.pid, sig)
            except ProcessLookupError:
                break
            try:
                child.proc.wait(wait)
                break
            except subprocess.TimeoutExpired:
                self.say(f'{child.name} did not stop on {sig.name}')

    def run(self) -> int:
        """Run the graph until the owner finishes, a node dies or a signal arrives."""
        if self.preflight:  # every params file checked before anything starts or is written
            check_config(self.config_dir, self.overrides)
        with isolation.reserved(self.describe()) as domain:
            self.run_id = isolation.new_run_id()
            for name in (*(n[0] for n in NODES), RECORDER[0]):
                self.overrides.setdefault(name, {})['run_id'] = self.run_id
            how = ('a free domain taken for this run' if domain.picked else 'ROS_DOMAIN_ID')
            self.say(f'ROS domain {domain.domain} ({how}), run identity {self.run_id}')
            return self._run()

    def describe(self) -> str:
        """Return how this run is named to another run that finds its domain taken."""
        where = f', bag {self.bag.resolve()}' if self.bag else ''
        return f'rths launch --config {self.config_dir.resolve()}{where}'

    def _run(self) -> int:
        previous = {s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
        failed = None
        try:
            self._start()
            t0 = time.monotonic()
            next_sample = t0
            while True:
                if self.cpu_sample_s and time.monotonic() >= next_sample:
                    next_sample += self.cpu_sample_s
                    self.cpu_samples.append((time.time_ns(), {
                        c.name: cpu_seconds(c.proc.pid) for c in self.children
                        if c.returncode is None}))
                if self._signal is not None:
                    self.say(f'{signal.Signals(self._signal).name} received: stopping all nodes')
                    break
                owner = self._child(self.owner)
                if owner.returncode == 0:
                    self._progress_done()
                    self.say('run finished')
                    break
                dead = [c for c in self.children if c.returncode is not None and not c.stopping]
                if dead and owner.returncode == 0:   # the owner exited since the check above
                    self.say('run finished')
                    break
                if dead:
                    failed = dead[0]
                    where = (f' in the container (pid {failed.proc.pid})'
                             if failed.name == 'container' else '')
                    self.say(f'node {self.culprit(failed)} died '
                             f'({describe_exit(failed.returncode)}){where}; stopping the others')
                    break
                if self.timeout_s and time.monotonic() - t0 > self.timeout_s:
                    failed = owner
                    self.say(f'timeout: the run did not finish within {self.timeout_s:g} s')
                    break
                time.sleep(0.02)
            if failed is not None and failed.name in ('numerical', 'compensator'):
                self.wait_for_bridge_safe_stop()  # the bridge's input stopped
        finally:
            # Loop order, recorder last, so the bag keeps everything that was published.
            for child in sorted(self.children, key=lambda c: c.name == 'recorder'):
                self.stop(child)
            for child in self.children:
                child.reader.join(timeout=2.0)
            if self.progress is not None:
                with self._print_lock:
                    self.progress.close()
                self.progress = None
            for s, handler in previous.items():
                signal.signal(s, handler)
            if self._tmp is not None:
                shutil.rmtree(self._tmp, ignore_errors=True)
        recorder = self._child('recorder')
        if recorder is not None and recorder.returncode != 0 and self.bag is not None:
            if self.bag.exists():
                reindex(self.bag)
                self.say(f'recorder ended with {describe_exit(recorder.returncode)}: '
                         f'bag {self.bag} reindexed')
        bridge = self._child('bridge') or self._child('container')
        if (bridge is not None and bridge.returncode is not None and bridge.returncode < 0
                and not bridge.stopping):
            self.safe_state_after_bridge_death(bridge)
        if failed is not None:
            self.say(f'FAILED: node {self.culprit(failed)} ({describe_exit(failed.returncode)})')
            return 1
        if self._signal is not None:
            return 128 + self._signal
        return 0

    def _start(self):
        """Start the recorder (if a bag is asked for) and the graph in its layout."""
        composed = self.layout == 'composed'
        read_fd = write_fd = -1
        if self.bag:
            recorder_over = self.overrides.setdefault('recorder', {})
            recorder_over.setdefault('bag', str(self.bag))
            recorder_over.setdefault('mode', self.mode)
            # the bag's provenance: the recorder keeps the files of the config directory
            recorder_over.setdefault('config_dir', str(self.config_dir.resolve()))
            # the recorder reads /rths/emergency_stop over DDS in both layouts: a stop of the
            # stability monitor must not come before it matched (it would miss it)
            self.overrides.setdefault('compensator', {}).setdefault('wait_for_stop_readers', 2)
            if composed:   # the container's tee brings the recorder every message
                read_fd, write_fd = os.pipe()
                recorder_over['pipe_fd'] = read_fd
            else:
                # each loop topic: its consumer and the recorder (see ns.wait_for_readers)
                for name in ('numerical', 'compensator', 'bridge'):
                    self.overrides.setdefault(name, {}).setdefault('wait_for_subscribers', 2)
        try:
            if self.bag:
                child = self._spawn('recorder', self._argv(*RECORDER),
                                    pass_fds=(read_fd,) if composed else ())
                self._wait_for_line(child, 'recording', 20.0)
            if composed:
                self._spawn('container', self._container_argv(write_fd),
                            pass_fds=(write_fd,) if write_fd >= 0 else ())
                return
            for spec in NODES:
                self._spawn(spec[0], self._argv(*spec))
        finally:
            for fd in (read_fd, write_fd):   # the children hold their ends now
                if fd >= 0:
                    os.close(fd)

    def bridge_param(self, key: str, default):
        """Return a bridge parameter from the overrides or bridge.yaml, else ``default``."""
        if key in self.overrides.get('bridge', {}):
            return self.overrides['bridge'][key]
        try:
            data = yamlfile.load(self.config_dir / 'bridge.yaml') or {}
            return data['bridge']['ros__parameters'].get(key, default)
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            return default

    def safe_stop_bound_s(self) -> float:
        """Stated time [s] within which the bridge reaches STOPPED once its input stops.

        Lock-step: the command watchdog (``watchdog_timeout_s``, checked every
        0.1 s), then HOLD (``hold_time_s``) and the RAMP (about ``ramp_time_s``,
        within the velocity/acceleration limits), plus 2 s for braking and
        process scheduling.  Realtime: ``watchdog_steps`` ticks instead of the
        lock-step watchdog.  Hold and ramp are counted in loop steps at fs: on a
        loaded machine the stop timer runs slower and the wall time grows.
        """
        hold = float(self.bridge_param('hold_time_s', 0.25))
        ramp = float(self.bridge_param('ramp_time_s', 2.0))
        if self.mode == 'realtime':
            detect = float(self.bridge_param('watchdog_steps', 10)) / float(
                self.bridge_param('fs_hz', 1024.0))
        else:
            detect = float(self.bridge_param('watchdog_timeout_s', 5.0)) + 0.1
        return detect + hold + ramp + 2.0

    def wait_for_bridge_safe_stop(self):
        """Return a loop node died: let the bridge's watchdog bring the plant to the safe state.

        The bridge notices that commands stopped, holds, ramps to the safe
        position and exits with code 3 (safety stop); the launcher waits up to
        :meth:`safe_stop_bound_s` for that before it stops the rest.
        """
        bridge = self._child('bridge')
        if bridge is None or bridge.returncode is not None:
            return
        bound = self.safe_stop_bound_s()
        self.say(f'waiting up to {bound:.2f} s for the bridge to reach the safe state')
        t0 = time.monotonic()
        stopped = False
        # The stop sequence is counted in loop steps at fs; a loaded machine runs the bridge's
        # stop timer slower than fs (the actuator then moves slower: the safe direction), so
        # the launcher gives up only after twice the stated time.
        while bridge.returncode is None and time.monotonic() - t0 < 2 * bound:
            if self._signal is not None:
                return
            if any('safety stop at step' in line for line in bridge.lines[-20:]):
                stopped = True
                break
            time.sleep(0.02)
        took = time.monotonic() - t0
        if stopped or bridge.returncode == 3:
            late = '' if took <= bound else ' (late: the machine is loaded)'
            self.say(f'bridge reached the safe state (safety stop) {took:.2f} s after the '
                     f'failure (bound {bound:.2f} s){late}')
            try:  # it exits by itself once its last messages are acknowledged (ns.flush)
                bridge.proc.wait(10.0)
            except subprocess.TimeoutExpired:
                pass
        else:
            self.say(f'bridge did not report a safety stop within {2 * bound:.2f} s '
                     f'({describe_exit(bridge.returncode)}); stopping it')

    def bridge_params(self) -> dict:
        """Return the bridge's parameters: its params file with the overrides."""
        try:
            data = yamlfile.load(self.config_dir / 'bridge.yaml') or {}
            params = dict(data['bridge']['ros__parameters'])
        except (OSError, ValueError, KeyError, TypeError):
            params = {}
        params.update(self.overrides.get('bridge', {}))
        return params

    def safe_state_after_bridge_death(self, bridge: Child):
        """Return the bridge was killed: say (and, with hardware, make sure) the plant is safe.

        The backend's class knows how (:meth:`rths_actuator_bridge.backend.Backend.make_safe`):
        the simulated plant lived in the bridge process and stopped with it; the UDP
        backend's servo controller is sent DEACTIVATE, so its own interlock holds the
        actuator (the emulator: ``rths controller-emulator``, udp.py).
        """
        # lazy: start-up cost: SciPy (~1 s), which this module needs only here
        from rths_actuator_bridge.bridge import backend_class

        params = self.bridge_params()
        try:
            self.say(f'bridge {describe_exit(bridge.returncode)}: '
                     + backend_class(params).make_safe(params))
        except (OSError, ValueError) as err:
            self.say(f'bridge {describe_exit(bridge.returncode)}: could not bring the actuator '
                     f'to rest ({err}); its controller\'s own command watchdog must stop it')

    def _child(self, name):
        return next((c for c in self.children if c.name == name), None)

    def _wait_for_line(self, child: Child, text: str, timeout_s: float):
        t_end = time.monotonic() + timeout_s
        while time.monotonic() < t_end:
            if any(text in line for line in child.lines):
                return
            if child.returncode is not None:
                raise OSError(f'{child.name} exited during start-up '
                              f'({describe_exit(child.returncode)})')
            time.sleep(0.02)
        raise OSError(f'{child.name} did not report {text!r} within {timeout_s:g} s')
