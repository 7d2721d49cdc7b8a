"""Helpers of the rths system tests: find the installed tools, run them, read bags."""

import os
from pathlib import Path
import re
import signal
import subprocess
import sys
import threading
import time


def _repo_root() -> Path:
    """Return the checkout (RTHS_ROOT, else the first parent holding config/ and Makefile)."""
    if os.environ.get('RTHS_ROOT'):
        return Path(os.environ['RTHS_ROOT'])
    for parent in Path(__file__).resolve().parents:
        if (parent / 'config').is_dir() and (parent / 'Makefile').is_file():
            return parent
    raise RuntimeError('cannot find the rths checkout; source env.sh first')


REPO = _repo_root()


def rths_executable() -> str:
    """Path of the installed ``rths`` command (found through the ament index)."""
    from ament_index_python.packages import get_package_prefix

    return str(Path(get_package_prefix('rths_bringup')) / 'lib' / 'rths_bringup' / 'rths')


def rths(*args, timeout=300, check=True, faults=None, **kwargs) -> subprocess.CompletedProcess:
    """Run ``rths ARGS`` and return the completed process (text output).

    ``faults`` (``{node: {fault: value}}``): the loop nodes of the run inject them
    (:mod:`rths_system_tests.faults`).
    """
    proc = subprocess.run([rths_executable(), *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, env=graph_env(faults), **kwargs)
    if check and proc.returncode != 0:
        sys.stderr.write(proc.stdout[-4000:] + proc.stderr[-4000:])
        raise AssertionError(f'rths {" ".join(map(str, args))} exited {proc.returncode}')
    return proc


def config_copy(directory: Path, **changes) -> Path:
    """Copy the repository's config/ to ``directory`` with ``{node: {key: value}}`` changes.

    ``config_copy(tmp_path / 'config', bridge={'watchdog_steps': 256})`` sets one key of
    bridge.yaml's ``ros__parameters``; every other file is copied as it is.
    """
    import shutil

    import yaml

    shutil.copytree(REPO / 'config', directory)
    for node, keys in changes.items():
        path = directory / f'{node}.yaml'
        doc = yaml.safe_load(path.read_text())
        doc[node]['ros__parameters'].update(keys)
        path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return directory


def graph_env(faults=None) -> dict:
    """Environment of a test run: a private ROS domain per pytest process, localhost only.

    ``faults``: an overlay of fault-injecting node executables in front (faults.overlay_env).
    """
    env = dict(os.environ)
    env.setdefault('ROS_DOMAIN_ID', str(20 + os.getpid() % 80))
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    env['RTHS_ROOT'] = str(REPO)
    if faults:
        from rths_system_tests.faults import overlay_env
        env = overlay_env(env, faults)
    return env


def started_pids(output: str) -> dict:
    """``{node: pid}`` from the launcher's 'started NAME (pid N)' lines."""
    return {m.group(1): int(m.group(2))
            for m in re.finditer(r'started (\w+) \(pid (\d+)\)', output)}


def launch_background(config, bag, *args, faults=None) -> subprocess.Popen:
    """``rths launch --config CONFIG --bag BAG ARGS`` running in the background (text stdout)."""
    return subprocess.Popen(
        [rths_executable(), 'launch', '--config', str(config), '--bag', str(bag),
         *map(str, args)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        env=graph_env(faults))


def wait_for(proc, text, timeout=90.0) -> str:
    """Read the launcher's output until ``text`` appears; return everything read."""
    seen = []
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        line = proc.stdout.readline()
        if not line:
            break
        seen.append(line)
        if text in line:
            return ''.join(seen)
    raise AssertionError(f'{text!r} not seen in launcher output:\n' + ''.join(seen[-50:]))


def committed_count(bag, topic) -> int:
    """Messages of ``topic`` already committed to a bag that is still being written (0 if none).

    MCAP: complete chunks in the file; sqlite3: committed rows (read-only; a busy
    or not yet created database counts as 0).
    """
    from rths_common.bagstore import committed_counts

    return int(committed_counts(bag).get(topic, 0))


class Drain:
    """Read a running process's text output in a thread, keeping all of it.

    While a test waits on the bag, nobody else reads the launcher's pipe: once it
    is full (64 KiB) the launcher blocks on writing, its nodes block on their log
    lines and the loop stops.  ``head``: what was read before.
    """

    def __init__(self, proc: subprocess.Popen, head: str = ''):
        self.proc = proc
        self.lines = [head]
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self):
        for line in self.proc.stdout:
            self.lines.append(line)

    def text(self, timeout: float = 30.0) -> str:
        """Everything read; after the process ended, wait (``timeout``) for the rest."""
        if self.proc.poll() is not None:
            self.thread.join(timeout)
        return ''.join(self.lines)


def wait_committed(bag, topics, count, timeout=60.0, drain: Drain | None = None) -> dict:
    """Wait until the bag holds more than ``count`` committed messages of every topic.

    ``drain``: the run's output; its process ending first fails at once, and a
    failure shows the end of the output.
    """
    t_end = time.monotonic() + timeout
    while True:
        have = {t: committed_count(bag, t) for t in topics}
        if min(have.values()) > count:
            return have
        ended = drain is not None and drain.proc.poll() is not None
        if ended or time.monotonic() > t_end:
            why = (f'the run ended (exit code {drain.proc.returncode}) after the recorder '
                   f'committed {have}' if ended else
                   f'the recorder committed only {have} within {timeout} s')
            tail = '' if drain is None else '; the run printed:\n' + drain.text()[-4000:]
            raise AssertionError(why + tail)
        time.sleep(0.1)


def wait_steps(bag, steps, timeout=90.0, drain: Drain | None = None) -> dict:
    """Wait until a running launch's bag holds ``steps`` committed measurements.

    (The launcher shows the run's progress on stderr, not the numerical node's
    ``progress: step`` log lines; the bag is what a test can rely on.)
    """
    from rths_common import topics

    return wait_committed(bag, [topics.MEASUREMENT], steps - 1, timeout, drain)


def sigkill_mid_run(proc, bag, victim, timeout=120.0) -> str:
    """SIGKILL node ``victim`` of a running ``rths launch`` once the loop is under way.

    Waits for step 1024 and then until the bag holds more than 100 committed steps
    of every loop topic: the recorder lags a lock-step loop under load and promises
    a loss bound in wall time (COMMIT_PERIOD_S plus one batch), not in steps (CI had
    committed 73 steps at step 1024).  Returns the launcher's whole output.
    """
    from rths_review.review import STEP_TOPICS

    head = wait_for(proc, 'graph connected')
    drain = Drain(proc, head)
    wait_steps(bag, 1024, drain=drain)              # one simulated second is done
    wait_committed(bag, STEP_TOPICS, 100, drain=drain)
    os.kill(started_pids(head)[victim], signal.SIGKILL)
    proc.wait(timeout=timeout)
    return drain.text()
