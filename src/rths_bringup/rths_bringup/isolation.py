"""Runs that cannot drive each other's actuator: a ROS domain of its own and a run identity.

Two safeguards, both on by default:

* **A ROS domain per run** (:func:`reserved`).  With ``ROS_DOMAIN_ID`` unset the run
  takes a free domain of 1..100 and its nodes run there; with ``ROS_DOMAIN_ID`` set
  the run takes that one.  A domain is taken the way ``domain_coordinator`` (the ROS
  test tools' package) does it: by binding the TCP port ``32768 + domain`` for as long
  as the run lasts, so the claim ends with the process however it ends.  Beside it a
  small file (``rths-domain-<domain>-<uid>.json`` in the temporary directory) names
  the run that holds it.  A run whose domain is taken on this host refuses to start
  and names the run that holds it (or the process, when it is not an rths run).
* **A run identity** (:func:`new_run_id`), given to every node of a run as the
  parameter ``run_id``: every loop message carries it and every node acts only on
  messages of its own run (:mod:`rths_common.transport`), so a run on another host
  in the same domain, or a stray publisher with the loop's node names, never moves
  the actuator.
"""

import contextlib
import datetime
import getpass
import json
import os
from pathlib import Path
import secrets
import socket
import tempfile

#: The domain coordinator's ports: domain d is held by whoever binds PORT_BASE + d.
PORT_BASE = 32768
#: Domains a run picks from when ``ROS_DOMAIN_ID`` is unset (the coordinator's range).
FREE_DOMAINS = range(1, 101)
#: Largest domain id Fast DDS maps to ports.
MAX_DOMAIN = 232

_held = {}   # domain -> [Reservation, count]: this process's claims (nested runs reuse them)


def new_run_id() -> str:
    """Return a fresh run identity: host, process and a random part."""
    return f'{socket.gethostname()}-{os.getpid()}-{secrets.token_hex(4)}'


class Reservation:
    """A claimed ROS domain: the bound port and the file that names the run."""

    def __init__(self, domain: int, sock: socket.socket, what: str, picked: bool):
        self.domain, self.sock, self.what, self.picked = domain, sock, what, picked
        self.owner_file = owner_dir() / f'rths-domain-{domain}-{os.getuid()}.json'
        info = {'pid': os.getpid(), 'user': _user(), 'host': socket.gethostname(),
                'what': what, 'started': datetime.datetime.now().isoformat(timespec='seconds')}
        try:
            self.owner_file.write_text(json.dumps(info))
        except OSError:
            self.owner_file = None      # the claim holds without the note

    def release(self):
        """Give the domain back."""
        if self.owner_file is not None:
            with contextlib.suppress(OSError):
                self.owner_file.unlink()
        self.sock.close()


def owner_dir() -> Path:
    """Directory of the files naming the runs that hold domains (``RTHS_DOMAIN_DIR`` or tmp)."""
    return Path(os.environ.get('RTHS_DOMAIN_DIR') or tempfile.gettempdir())


def _user() -> str:
    try:
        return getpass.getuser()
    except (KeyError, OSError):
        return str(os.getuid())


def _bind(domain: int):
    """Return a socket bound to the domain's port, None if someone holds it."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    try:
        sock.bind(('', PORT_BASE + domain))
    except OSError:
        sock.close()
        return None
    return sock


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def holder(domain: int) -> str:
    """Describe who holds ``domain`` on this host (the rths run, else the port's owner)."""
    for path in sorted(owner_dir().glob(f'rths-domain-{domain}-*.json')):
        try:
            info = json.loads(path.read_text())
            pid = int(info['pid'])
        except (OSError, ValueError, KeyError, TypeError):
            continue
        if _alive(pid):
            return (f"another rths run: {info.get('what', '?')} (pid {pid}, user "
                    f"{info.get('user', '?')}, started {info.get('started', '?')})")
    return (f'another process on this host (it holds TCP port {PORT_BASE + domain}, the ROS '
            'domain coordinator\'s claim on that domain)')


def requested_domain(env) -> int | None:
    """Return the ``ROS_DOMAIN_ID`` of ``env`` (None if unset; ValueError if not a domain)."""
    text = str(env.get('ROS_DOMAIN_ID', '') or '').strip()
    if not text:
        return None
    try:
        domain = int(text)
    except ValueError:
        domain = -1
    if not 0 <= domain <= MAX_DOMAIN:
        raise ValueError(f'ROS_DOMAIN_ID={text!r}: give a ROS domain 0..{MAX_DOMAIN}, or unset '
                         'it and each run takes a free domain of its own')
    return domain


def claim(env, what: str) -> Reservation:
    """Claim the run's ROS domain (``env``'s ``ROS_DOMAIN_ID``, else a free one); see module doc.

    A domain this process already holds is shared (a run's phases). ValueError,
    naming the run that holds it, when the domain is taken.
    """
    domain = requested_domain(env)
    if domain is not None and domain in _held:
        _held[domain][1] += 1
        return _held[domain][0]
    if domain is not None:
        sock = _bind(domain)
        if sock is None:
            raise ValueError(f'ROS domain {domain} (ROS_DOMAIN_ID) is in use by {holder(domain)}; '
                             'two runs in one domain would drive each other\'s actuator: wait '
                             'for it to end, or unset ROS_DOMAIN_ID and this run takes a free '
                             'domain of its own')
        reservation = Reservation(domain, sock, what, picked=False)
    else:
        start = os.getpid() % len(FREE_DOMAINS)
        for i in range(len(FREE_DOMAINS)):
            candidate = FREE_DOMAINS[(start + i) % len(FREE_DOMAINS)]
            sock = _bind(candidate)
            if sock is not None:
                break
        else:
            raise ValueError(f'no free ROS domain among {FREE_DOMAINS.start}..'
                             f'{FREE_DOMAINS.stop - 1} on this host; end a run, or set '
                             'ROS_DOMAIN_ID to a free domain')
        reservation = Reservation(candidate, sock, what, picked=True)
    _held[reservation.domain] = [reservation, 1]
    return reservation


def release(reservation: Reservation):
    """Release one claim of ``reservation`` (the domain is free once every claim is released)."""
    entry = _held.get(reservation.domain)
    if entry is None:
        return
    entry[1] -= 1
    if entry[1] <= 0:
        del _held[reservation.domain]
        reservation.release()


@contextlib.contextmanager
def reserved(what: str, env=None):
    """Hold the run's ROS domain while the body runs; its nodes inherit ``ROS_DOMAIN_ID``.

    ``env`` (default ``os.environ``) gets ``ROS_DOMAIN_ID`` of a picked domain for
    the body's duration.  Yields the :class:`Reservation`.
    """
    env = os.environ if env is None else env
    reservation = claim(env, what)
    before = env.get('ROS_DOMAIN_ID')
    env['ROS_DOMAIN_ID'] = str(reservation.domain)
    try:
        yield reservation
    finally:
        if before is None:
            env.pop('ROS_DOMAIN_ID', None)
        else:
            env['ROS_DOMAIN_ID'] = before
        release(reservation)
