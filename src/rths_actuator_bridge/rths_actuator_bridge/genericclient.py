"""A remote experimental site as the specimen (``backend: genericclient``, ``--specimen tcp://``).

The bridge speaks the OpenSees ``genericClient`` protocol (:mod:`.openfresco`)
to a site: an OpenFresco ``SimAppSiteServer``/experimental site, or another
rths (``rths site``).  Per loop step k::

    write(u_k):  setTrialResponse(disp u_k, vel, accel, time k/fs); commitState if k > 0
    read():      getDaqResponse -> measured displacement (daq disp) and force

The trial carries the velocity and acceleration of the commands (backward
differences at ``fs_hz``).  Step 0 is sent as OpenSees sends the structure at
rest, a trial without a commit; every later step commits before it reads, so
each reading is the one of this step, also when a trial repeats the previous
displacement (an rths site then steps at the commit).  The set-up asks for the
daq displacement and force
(``sizeDaq = n, 0, 0, n, 0``).  A site that does not answer within
``site_timeout_s``, closes the connection or answers with non-finite numbers makes
``read()`` return NaN (as the UDP backend on a lost reply): the safety
supervisor counts it and stops the run after ``max_invalid_measurements``.
"""

import socket
import ssl
import time
from urllib.parse import urlsplit

import numpy as np

from . import openfresco as of
from .backend import Backend

#: Generic-client parameters: key -> (type, default, meaning with unit).
CLIENT_PARAMS = {
    'site': (str, '', 'tcp://host:port of the experimental site (rths site, OpenFresco)'),
    'n_channels': (int, 1, '[-] number of actuators = basic DOFs of the element'),
    'site_timeout_s': (float, 5.0, '[s] connect and reply timeout of the site'),
    'data_size': (int, 256, '[-] float64 per message (genericClient default 256)'),
    'tls_ca': (str, '', 'CA certificate (PEM) that signed the site: TLS on (empty: plain TCP)'),
    'tls_cert': (str, '', 'client certificate (PEM) for mutual TLS (empty: none)'),
    'tls_key': (str, '', 'private key (PEM) of tls_cert'),
}
#: Ranges of :data:`CLIENT_PARAMS` (inclusive).
CLIENT_RANGES = {'site_timeout_s': (0.001, 3600.0), 'data_size': (1, of.MAX_DATA_SIZE)}


def parse_site(url: str) -> tuple:
    """Return ``(host, port)`` of ``tcp://host:port`` (ValueError naming the fix)."""
    parts = urlsplit(str(url))
    try:
        port = parts.port
    except ValueError:
        port = None
    if parts.scheme != 'tcp' or not parts.hostname or not port:
        raise ValueError(f"parameter 'site' = {url!r} must be tcp://host:port, e.g. "
                         'tcp://127.0.0.1:8090 (the address rths site or OpenFresco listens on)')
    return parts.hostname, port


def client_tls_context(ca: str, cert: str = '', key: str = ''):
    """Return an SSL context that checks the site against ``ca`` and shows ``cert`` if given."""
    ctx = ssl.create_default_context(ssl.Purpose.SERVER_AUTH, cafile=ca)
    ctx.check_hostname = False   # sites are addressed by IP in a lab; the CA pins the peer
    if cert:
        ctx.load_cert_chain(cert, key or None)
    return ctx


class GenericClientBackend(Backend):
    """The bridge as an OpenSees ``genericClient`` of a remote site (module docstring)."""

    summary = 'a remote experimental site (rths site, OpenFresco) over the genericClient protocol'
    params = CLIENT_PARAMS
    ranges = CLIENT_RANGES

    @classmethod
    def make_safe(cls, params: dict) -> str:
        """After the bridge process died: the site stops its own actuator (say so)."""
        return ('the remote site lost its client: rths site takes its actuator to the safe '
                'state by itself (an OpenFresco site: check its own safety)')

    def _configure(self, params: dict):
        p = {key: params.get(key, default) for key, (_, default, _) in CLIENT_PARAMS.items()}
        self.host, self.port = parse_site(p['site'])
        n = p['n_channels']
        if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= 64:
            raise ValueError(f"parameter 'n_channels' = {n!r} must be an integer in [1, 64]")
        if not 0 < float(p['site_timeout_s']) <= 3600:
            raise ValueError(f"parameter 'site_timeout_s' = {p['site_timeout_s']} must be in "
                             '(0, 3600] s')
        self.n_channels = n
        self.fs_hz = float(self.limits.fs_hz)
        self.timeout_s = float(p['site_timeout_s'])
        self.sizes = of.Sizes.generic_client(n, int(p['data_size']), daq_disp=True)
        self.tls = (p['tls_ca'], p['tls_cert'], p['tls_key']) if p['tls_ca'] else None
        self.sock = None
        self.error = ''

    def _connect(self):
        try:
            sock = socket.create_connection((self.host, self.port), timeout=self.timeout_s)
        except OSError as err:
            raise OSError(f'site tcp://{self.host}:{self.port} does not answer ({err}); is '
                          'rths site (or the OpenFresco site) running there?') from None
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        if self.tls:
            sock = client_tls_context(*self.tls).wrap_socket(sock)
        return sock

    def _activate(self):
        self.sock = self._connect()
        self.sock.sendall(self.sizes.pack())
        self.error = ''
        self._history = np.zeros((2, self.n_channels))
        self._commands = 0

    def _send(self, data: bytes) -> bool:
        if self.sock is None:
            return False
        try:
            self.sock.sendall(data)
            return True
        except OSError as err:
            self._lost(f'sending to the site failed ({err})')
            return False

    def _lost(self, text: str):
        self.error = self.error or text
        if self.sock is not None:
            self.sock.close()
            self.sock = None

    def _write(self, command):
        h = self._history
        vel = (command - h[0]) * self.fs_hz if self._commands else np.zeros_like(command)
        acc = (command - 2 * h[0] + h[1]) * self.fs_hz ** 2 if self._commands > 1 \
            else np.zeros_like(command)
        h[1], h[0] = h[0], command
        t = self._commands / self.fs_hz
        self._commands += 1
        trial = of.encode_request(self.sizes, of.SET_TRIAL_RESPONSE, command, vel, acc, time=t)
        if self._commands > 1:   # step 0 is the structure at rest, as OpenSees sends it
            trial += of.encode_request(self.sizes, of.COMMIT_STATE, time=t)
        self._send(trial)

    def _recv_exact(self, size: int):
        data = bytearray()
        deadline = time.monotonic() + self.timeout_s
        while len(data) < size:
            left = deadline - time.monotonic()
            if left <= 0:
                self._lost(f'the site sent no reply within site_timeout_s {self.timeout_s:g} s')
                return None
            self.sock.settimeout(left)
            try:
                chunk = self.sock.recv(size - len(data))
            except OSError as err:
                self._lost(f'receiving from the site failed ({err})')
                return None
            if not chunk:
                self._lost('the site closed the connection')
                return None
            data += chunk
        return bytes(data)

    def _read(self):
        nan = np.full(self.n_channels, np.nan)
        if not self._send(of.encode_request(self.sizes, of.GET_DAQ_RESPONSE)):
            return nan, nan.copy()
        reply = self._recv_exact(self.sizes.message_bytes)
        if reply is None:
            return nan, nan.copy()
        daq = of.decode_reply(reply, self.sizes)
        return daq['disp'].copy(), daq['force'].copy()

    def _deactivate(self):
        if self.sock is not None:
            self._send(of.encode_request(self.sizes, of.DIE))
            self._lost('deactivated')

    def close(self):
        """Say goodbye to the site (die) and close the connection."""
        super().close()
        if self.sock is not None:
            self._lost('closed')
