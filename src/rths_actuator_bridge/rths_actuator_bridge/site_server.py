"""``rths site``: the TCP shell of the experimental site (one client session, one bag).

Moves bytes between one OpenSees ``genericClient`` (or OpenFresco client) and
:class:`.site.SiteCore`; the protocol is :mod:`.openfresco`.  Runs in its own
process: OpenSeesPy holds the GIL during ``analyze()``, so a site in the
client's process would stall.

Socket: binds 127.0.0.1 unless told otherwise; ``TCP_NODELAY`` (the replies
go out at once) and ``TCP_QUICKACK`` re-armed after every receive (Linux
clears it again: without it the client's back-to-back sends meet the site's
delayed ACK and a step takes ~40 ms instead of ~0.1 ms).  Optional TLS
(``tls_cert``/``tls_key``; with ``tls_ca`` the client must show a certificate
signed by it: mutual authentication) and an allow-list of client addresses.

Bad peers end the session safely: a set-up or message that breaks the
protocol (:class:`.openfresco.ProtocolError`: truncated, wrong size, not
finite, unknown action), a client that closes or falls silent for
``client_timeout_s`` before saying goodbye (``die``/``shutdown``), and a
second client connecting during the session.  Each gets one log line, the
supervisor takes the actuator to its safe state (:meth:`.site.SiteCore.safe_stop`)
and the bag is closed readable.
"""

import ipaddress
import socket
import ssl
import sys
import threading
import time

from rths_common.stepping import TickClock

from . import openfresco as of
from .site import SiteStopped, build_site

#: Exit codes of :func:`serve`: 0 the client said goodbye, 3 a safety stop (bad peer, fault).
EXIT_DONE, EXIT_SAFETY_STOP = 0, 3
_QUICKACK = getattr(socket, 'TCP_QUICKACK', None)


def log(text: str):
    """One line on stderr, prefixed as every site message is."""
    print(f'[site] {text}', file=sys.stderr, flush=True)


def allowed(address: str, allow) -> bool:
    """Return True if ``address`` is one of ``allow`` (addresses or CIDR networks)."""
    try:
        ip = ipaddress.ip_address(address.split('%')[0])
    except ValueError:
        return False
    if ip.version == 6 and ip.ipv4_mapped:
        ip = ip.ipv4_mapped
    for entry in allow:
        net = ipaddress.ip_network(entry, strict=False)
        if ip.version == net.version and ip in net:
            return True
    return False


def check_allow(allow) -> list:
    """Return the allow-list, refusing an entry that is no address or network."""
    for entry in allow:
        try:
            ipaddress.ip_network(entry, strict=False)
        except ValueError:
            raise ValueError(f'allow-list entry {entry!r} is no IP address or network (e.g. '
                             '127.0.0.1 or 10.0.0.0/24)') from None
    return list(allow)


def server_tls_context(cert: str, key: str, ca: str = ''):
    """Return the site's SSL context; with ``ca`` the client must show a certificate it signed."""
    if not cert:
        raise ValueError('--tls-key/--tls-ca need --tls-cert (the site certificate, PEM)')
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    try:
        ctx.load_cert_chain(cert, key or None)
        if ca:
            ctx.load_verify_locations(ca)
            ctx.verify_mode = ssl.CERT_REQUIRED
    except (OSError, ssl.SSLError) as err:
        raise OSError(f'TLS files --tls-cert {cert} --tls-key {key} --tls-ca {ca}: {err}') \
            from None
    return ctx


def listen(host: str, port: int) -> socket.socket:
    """Return a listening TCP socket on ``host:port`` (port 0: any free one)."""
    family = socket.AF_INET6 if ':' in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as err:
        sock.close()
        raise OSError(f'cannot listen on {host}:{port} ({err}); choose another --port or '
                      '--host') from None
    sock.listen(4)
    return sock


def tune(conn: socket.socket):
    """Send replies at once (TCP_NODELAY), ACKs at once (TCP_QUICKACK, re-armed per receive)."""
    conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    if _QUICKACK is not None:
        conn.setsockopt(socket.IPPROTO_TCP, _QUICKACK, 1)


class Session:
    """One client on the site: the byte loop, the second-client watch, the realtime clock."""

    def __init__(self, core, listener, conn, peer, params, tls=None):
        """Take the accepted ``conn`` from ``peer`` for ``core``."""
        self.core, self.listener, self.conn, self.peer = core, listener, conn, peer
        self.params, self.tls = params, tls
        self.problem = ''          # why the session ends badly ('' : goodbye)
        self.done = threading.Event()

    def run(self) -> str:
        """Serve the client until goodbye or a bad peer; return the problem ('' if none)."""
        watcher = threading.Thread(target=self._watch, daemon=True)
        watcher.start()
        clock = None
        if self.core.realtime:
            clock = threading.Thread(target=self._clock, daemon=True)
            clock.start()
        try:
            self._serve()
        except of.ProtocolError as err:
            self._fail(str(err))
        except SiteStopped as err:
            self._fail(str(err))
        except OSError as err:
            if not self.problem:
                self._fail(f'the connection failed mid-run ({err}): the client vanished')
        finally:
            self.done.set()
            if clock is not None:
                clock.join()
            self._close()
        return self.problem

    def _fail(self, text: str):
        if not self.problem:
            self.problem = text

    def _close(self):
        try:
            self.conn.close()
        except OSError:
            pass

    def _serve(self):
        core, conn = self.core, self.conn
        framer = of.Framer()
        conn.settimeout(float(self.params['client_timeout_s']))
        quickack = _QUICKACK
        while not self.done.is_set():
            try:
                data = conn.recv(1 << 16)
            except socket.timeout:
                raise OSError(f'no message for client_timeout_s '
                              f'{self.params["client_timeout_s"]:g} s') from None
            if quickack is not None and data:
                conn.setsockopt(socket.IPPROTO_TCP, quickack, 1)
            if not data:
                if self.problem:
                    return
                truncated = framer.truncation()
                raise of.ProtocolError(truncated or 'the client closed the connection before '
                                       'saying goodbye (die/shutdown): it vanished')
            for unit in framer.feed(data):
                if isinstance(unit, of.Sizes):
                    core.accept(unit)
                    log(f'client {self.peer}: {unit.n} basic DOF(s), dataSize '
                        f'{unit.data_size}; mode {self.params["mode"]}')
                    continue
                request = of.decode(unit, core.sizes)
                reply = core.handle(request)
                if reply is not None:
                    conn.sendall(reply)
                elif request.action in of.ENDS:
                    log(f'client {self.peer} said goodbye ({request.name}) after '
                        f'{core.commits} committed steps')
                    return
                if core.stopped:   # the realtime clock stopped on a fault
                    raise SiteStopped(core.stopped)

    def _watch(self):
        """Watch for a second connection: refuse it; an allowed one stops the run."""
        self.listener.settimeout(0.1)
        while not self.done.is_set():
            try:
                conn, addr = self.listener.accept()
            except (socket.timeout, OSError):
                continue
            peer = addr[0]
            conn.close()
            if not allowed(peer, self.params['allow']):
                log(f'refused {peer}: not on the allow-list (session with {self.peer} goes on)')
                continue
            self._fail(f'a second client ({peer}) connected while {self.peer} runs: one '
                       'specimen cannot serve two models')
            self._wake()
            return

    def _wake(self):
        try:
            self.conn.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass

    def _clock(self):
        """Realtime: tick the site's loop at fs_hz from the first trial on."""
        core = self.core
        while not core.started():
            if self.done.wait(0.0005):
                return
        clock = TickClock(core.fs_hz)
        clock.start(time.monotonic_ns())
        while not self.done.is_set():
            delay = clock.due_ns() - time.monotonic_ns()
            if delay > 0:
                time.sleep(delay / 1e9)
            _, _, skipped = clock.take(time.monotonic_ns())
            if skipped:
                core.bridge.supervisor.stalled(int(skipped), core.k)
            try:
                core.tick()
            except SiteStopped as err:
                self._fail(str(err))
                self._wake()
                return


def accept_client(listener, allow, tls, stop_at=None):
    """Wait for the first allowed client; return ``(conn, peer)`` or None at ``stop_at``."""
    while True:
        if stop_at is not None:
            left = stop_at - time.monotonic()
            if left <= 0:
                return None
            listener.settimeout(min(left, 0.5))
        else:
            listener.settimeout(None)
        try:
            conn, addr = listener.accept()
        except socket.timeout:
            continue
        peer = addr[0]
        if not allowed(peer, allow):
            log(f'refused {peer}: not on the allow-list {allow}')
            conn.close()
            continue
        tune(conn)
        if tls is not None:
            try:
                conn = tls.wrap_socket(conn, server_side=True)
            except OSError as err:
                log(f'refused {peer}: TLS handshake failed ({err})')
                conn.close()
                continue
        return conn, peer


def serve(core, listener, params, tls=None, wait_s=None) -> tuple:
    """Serve one client session on ``listener``; return ``(exit code, problem text)``."""
    got = accept_client(listener, params['allow'], tls,
                        None if wait_s is None else time.monotonic() + wait_s)
    if got is None:
        return EXIT_DONE, 'no client connected'
    conn, peer = got
    session = Session(core, listener, conn, peer, params, tls)
    problem = session.run()
    if problem:
        log(f'bad peer {peer}: {problem}; the actuator goes to its safe state')
        steps = core.safe_stop(problem)
        log(f'safe state reached in {steps} steps: {core.summary()["fault"]}')
        if core.recorder is not None:
            core.recorder.event(f'bad peer {peer}: {problem}')
        return EXIT_SAFETY_STOP, problem
    core.finish()
    if core.recorder is not None:
        core.recorder.event(f'client {peer} said goodbye')
    return EXIT_DONE, ''


def run(config: dict, listener, bag, tls=None, wait_s=None) -> dict:
    """Build the site from ``config``, serve one session on ``listener``, close; the summary.

    The summary: :meth:`.site.SiteCore.summary` with ``exit_code`` (0 goodbye, 3 safety
    stop), ``problem`` (the bad peer's fault, '' if none) and ``bag``.
    """
    site = config['site']
    core = build_site(config, bag, log)
    host, port = listener.getsockname()[:2]
    log(f'listening on {host}:{port} ({"TLS" if tls else "TCP"}; {site["mode"]}; backend '
        f'{config["bridge"].get("backend", "simulated")}, {core.n} interface DOF(s) at '
        f'{core.fs_hz:g} Hz); bag {bag}')
    code, problem = 2, 'the site failed'
    try:
        code, problem = serve(core, listener, site, tls, wait_s)
    except KeyboardInterrupt:   # Ctrl-C or SIGTERM (the CLI maps it): stop safely, keep the bag
        problem, code = 'the operator interrupted the site (Ctrl-C/SIGTERM)', EXIT_SAFETY_STOP
        log(f'{problem}; the actuator goes to its safe state')
        core.safe_stop(problem)
        if core.recorder is not None:
            core.recorder.event(problem)
    finally:
        if core.recorder is not None:
            core.recorder.close()
        core.bridge.close()
        summary = dict(core.summary(), exit_code=code, problem=problem, bag=str(bag))
        log(f'done: {summary["steps"]} loop steps, {summary["commits"]} commits, '
            f'{summary["messages"]} messages, safety state {summary["safety_state"]}'
            f'{", " + summary["fault"] if summary["fault"] else ""}; bag {bag} closed')
    return summary
