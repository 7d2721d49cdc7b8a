"""Every process of a run dies with the launcher that supervises it (Linux).

The launcher (``rths run`` / ``rths launch``) puts its pid in the environment of
each child (:data:`ENV`). A child calls :func:`bind` first thing: the kernel then
sends it a signal the moment the launcher dies, whatever killed it (SIGKILL
included, ``prctl(PR_SET_PDEATHSIG)``), and if the launcher died before the child
got that far the child signals itself. What the child does then:

* ``bind(stop=True)`` (numerical, compensator): the process then gets SIGTERM,
  the node's ordinary clean stop;
* ``bind()`` (the bridge, the composed container, the recorder): a flag is raised
  (:func:`lost`); the bridge then brings the actuator to its safe position
  through its safety supervisor (hold, ramp, stop) before it exits, and the
  recorder keeps recording that ramp before it closes the bag.

The launcher read the children's output; once it is gone a write to that pipe
would fail (BrokenPipeError in the middle of closing a bag), so the signal also
points the process's stdout and stderr at /dev/null.

Without :data:`ENV` (a node started by hand) :func:`bind` does nothing.
"""

import ctypes
import os
import signal

#: Environment variable holding the launcher's pid.
ENV = 'RTHS_LAUNCHER_PID'
#: The signal the kernel sends a child when its launcher dies.
LOST_SIGNAL = signal.SIGHUP
#: Longest wait [s] for readers to acknowledge the last messages once the launcher died.
LOST_FLUSH_S = 0.1
_PR_SET_PDEATHSIG = 1
_STATE: dict = {'launcher': None, 'lost': False, 'stop': False}


def launcher_env() -> dict:
    """Return the environment entry a launcher gives its children (its own pid)."""
    return {ENV: str(os.getpid())}


def bind(stop: bool = False) -> bool:
    """Have this process told when its launcher dies; True if bound.

    The death sets :func:`lost`, silences stdout/stderr and, with ``stop``, sends
    this process SIGTERM. If the launcher is already gone, that happens at once.
    """
    pid = os.environ.get(ENV, '')
    if not pid.isdigit():
        return False
    _STATE.update(launcher=int(pid), stop=stop)
    signal.signal(LOST_SIGNAL, _on_lost)
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.prctl(_PR_SET_PDEATHSIG, int(LOST_SIGNAL), 0, 0, 0) != 0:
        return False
    if os.getppid() != int(pid) and not _alive(int(pid)):
        os.kill(os.getpid(), LOST_SIGNAL)   # it died before the prctl above took effect
    return True


def lost() -> bool:
    """Return True once the launcher died (after :func:`bind` with :data:`LOST_SIGNAL`)."""
    return bool(_STATE['lost'])


def end_if_lost(code: int) -> None:
    """After the launcher died nobody waits for this process: end it with ``code`` now.

    Call it once the process's work is saved; it skips the interpreter's teardown
    (with rclpy about 1.5 s), which would keep the run's processes alive past 1 s.
    """
    if _STATE['lost']:
        os._exit(int(code))


def describe() -> str:
    """Return the text a node logs when its launcher died."""
    return f"the launcher (pid {_STATE['launcher']}) died"


def _on_lost(_signum, _frame):
    if _STATE['lost']:
        return
    _STATE['lost'] = True
    sink = os.open(os.devnull, os.O_WRONLY)
    for fd in (1, 2):
        os.dup2(sink, fd)
    os.close(sink)
    if _STATE['stop']:
        os.kill(os.getpid(), signal.SIGTERM)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True
