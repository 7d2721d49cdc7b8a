"""The OpenSees ``genericClient`` / OpenFresco wire protocol: framing and actions, no sockets.

An OpenSees ``genericClient`` element (and OpenFresco's ``SimAppSiteServer``
clients) talk to an experimental site over one TCP connection:

1. Set-up, client -> site: 11 native int32 (little-endian on every machine
   rths runs on)::

       sizeCtrl  disp, vel, accel, force, time     what the client sends per trial
       sizeDaq   disp, vel, accel, force, time     what it expects back per reading
       dataSize                                    float64 values in every later message

   ``genericClient`` with ``n`` basic DOFs sends ``(n, n, n, 0, 1, 0, 0, 0, n, 0,
   dataSize)``, ``dataSize = max(256, 1 + 3 n + 1, n * n)`` unless set.
2. Then every message, both ways, is exactly ``dataSize`` float64.  Value 0 of a
   client message is the action (:data:`ACTIONS`); ``setTrialResponse`` carries
   the ctrl vectors after it: ``disp[sizeCtrl.disp], vel[...], accel[...],
   force[...], time[...]``.  Only the get-actions (:data:`REPLIED`) are
   answered: a reading (``getDaqResponse``: the daq vectors in the same order;
   ``getDisp`` .. ``getTime``: one of them) or an ``n x n`` matrix in column
   order (``getInitialStiff`` .. ``getMass``), padded with zeros.

This module is the codec both directions share (:mod:`.site` serves it,
:mod:`.genericclient` speaks it): :class:`Sizes` (the set-up), :func:`decode`
(one client message -> :class:`Request`, refusing every malformed one with a
:class:`ProtocolError` that names what is wrong), :func:`encode_reply`,
:func:`encode_matrix`, :func:`encode_request` and :class:`Framer` (bytes of a
stream -> whole messages).
"""

from dataclasses import dataclass
import struct

import numpy as np

SET_TRIAL_RESPONSE = 3
COMMIT_STATE = 5
GET_DAQ_RESPONSE = 6
GET_DISP, GET_VEL, GET_ACCEL, GET_FORCE, GET_TIME = 7, 8, 9, 10, 11
GET_INITIAL_STIFF, GET_TANGENT_STIFF, GET_DAMP, GET_MASS = 12, 13, 14, 15
SHUTDOWN = 98
DIE = 99

#: Action number -> the name OpenSees/OpenFresco give it.
ACTIONS = {
    SET_TRIAL_RESPONSE: 'setTrialResponse', COMMIT_STATE: 'commitState',
    GET_DAQ_RESPONSE: 'getDaqResponse', GET_DISP: 'getDisp', GET_VEL: 'getVel',
    GET_ACCEL: 'getAccel', GET_FORCE: 'getForce', GET_TIME: 'getTime',
    GET_INITIAL_STIFF: 'getInitialStiff', GET_TANGENT_STIFF: 'getTangentStiff',
    GET_DAMP: 'getDamp', GET_MASS: 'getMass', SHUTDOWN: 'shutdown', DIE: 'die',
}
#: Actions the site answers with one message.
REPLIED = frozenset(range(GET_DAQ_RESPONSE, GET_MASS + 1))
#: Actions that answer with an n x n matrix.
MATRICES = frozenset((GET_INITIAL_STIFF, GET_TANGENT_STIFF, GET_DAMP, GET_MASS))
#: Actions that end the session (no answer).
ENDS = frozenset((SHUTDOWN, DIE))
#: Names of the five vectors of sizeCtrl / sizeDaq, in wire order.
RESPONSES = ('disp', 'vel', 'accel', 'force', 'time')
#: Largest dataSize accepted (a corrupt set-up must not make the site allocate gigabytes).
MAX_DATA_SIZE = 65536
SETUP = struct.Struct('<11i')


class ProtocolError(ValueError):
    """A peer broke the protocol; the message says how."""


@dataclass(frozen=True)
class Sizes:
    """The 11-integer set-up: vector sizes per message and ``data_size`` [float64]."""

    ctrl: tuple
    daq: tuple
    data_size: int

    @classmethod
    def generic_client(cls, n: int, data_size: int = 256, daq_disp: bool = False) -> 'Sizes':
        """Return what a ``genericClient`` of ``n`` basic DOFs sends (``daq_disp``: also disp)."""
        data_size = max(int(data_size), 1 + 3 * n + 1, n * n, 2 * n)
        return cls((n, n, n, 0, 1), (n if daq_disp else 0, 0, 0, n, 0), data_size)

    @classmethod
    def unpack(cls, data: bytes) -> 'Sizes':
        """Parse and check the 44 set-up bytes (ProtocolError if they cannot be a set-up)."""
        if len(data) != SETUP.size:
            raise ProtocolError(f'set-up of {len(data)} bytes; expected {SETUP.size} '
                                '(11 int32: sizeCtrl[5], sizeDaq[5], dataSize)')
        values = SETUP.unpack(data)
        sizes = cls(tuple(values[:5]), tuple(values[5:10]), values[10])
        sizes.check()
        return sizes

    def pack(self) -> bytes:
        """Return the 44 set-up bytes."""
        return SETUP.pack(*self.ctrl, *self.daq, self.data_size)

    @property
    def n(self) -> int:
        """Return the basic DOFs of the element: the size of the trial displacement."""
        return self.ctrl[0]

    def check(self):
        """Raise ProtocolError unless the sizes are a usable set-up."""
        text = f'set-up sizeCtrl {list(self.ctrl)}, sizeDaq {list(self.daq)}, ' \
               f'dataSize {self.data_size}'
        if min(self.ctrl + self.daq) < 0 or not 1 <= self.data_size <= MAX_DATA_SIZE:
            raise ProtocolError(f'{text}: sizes must be >= 0 and dataSize 1..{MAX_DATA_SIZE} '
                                '(is the peer an OpenSees genericClient?)')
        if self.ctrl[0] < 1 or self.ctrl[4] > 1 or self.daq[4] > 1:
            raise ProtocolError(f'{text}: needs a trial displacement (sizeCtrl disp >= 1) and '
                                'at most one time value')
        if 1 + sum(self.ctrl) > self.data_size or sum(self.daq) > self.data_size \
                or self.n * self.n > self.data_size:
            raise ProtocolError(f'{text}: dataSize is too small for 1 + sum(sizeCtrl), '
                                'sum(sizeDaq) and n*n values')
        for i, name in enumerate(RESPONSES[:4]):
            for side, sizes in (('sizeCtrl', self.ctrl), ('sizeDaq', self.daq)):
                if sizes[i] not in (0, self.n):
                    raise ProtocolError(f'{text}: {side} {name} = {sizes[i]} must be 0 or n = '
                                        f'{self.n} (one value per basic DOF)')

    def check_interface(self, n_interface: int, where: str = 'the site'):
        """Raise ProtocolError unless the client's n equals the ``n_interface`` DOFs configured."""
        if self.n != n_interface:
            raise ProtocolError(
                f'the client has {self.n} basic DOF(s) (sizeCtrl disp = {self.n}) but '
                f'{where} drives {n_interface} interface DOF(s): give the genericClient '
                f'element exactly {n_interface} -dof entries, or configure the site with '
                f'{self.n} channel(s); nothing was moved')

    @property
    def message_bytes(self) -> int:
        """Bytes of every message after the set-up."""
        return 8 * self.data_size


@dataclass
class Request:
    """One decoded client message: its action and, for a trial, the ctrl vectors."""

    action: int
    disp: np.ndarray
    vel: np.ndarray
    accel: np.ndarray
    force: np.ndarray
    time: float

    @property
    def name(self) -> str:
        """Return the action's OpenSees name."""
        return ACTIONS[self.action]


_EMPTY = np.zeros(0)


def decode(message: bytes, sizes: Sizes) -> Request:
    """Decode one whole client message (ProtocolError: wrong size, unknown action, nan/inf)."""
    if len(message) != sizes.message_bytes:
        raise ProtocolError(f'message of {len(message)} bytes; the set-up says dataSize '
                            f'{sizes.data_size} float64 = {sizes.message_bytes} bytes')
    head = struct.unpack_from('<d', message)[0]
    if not np.isfinite(head) or head != int(head) or int(head) not in ACTIONS:
        known = ', '.join(f'{k} {v}' for k, v in ACTIONS.items())
        raise ProtocolError(f'unknown action {head!r} (known: {known})')
    action = int(head)
    if action not in (SET_TRIAL_RESPONSE, COMMIT_STATE):
        return Request(action, _EMPTY, _EMPTY, _EMPTY, _EMPTY, float('nan'))
    used = 1 + sum(sizes.ctrl)
    values = np.frombuffer(message, '<f8', count=used)
    if not np.all(np.isfinite(values)):
        bad = int(np.argmax(~np.isfinite(values)))
        raise ProtocolError(f'{ACTIONS[action]} value {bad} is {values[bad]} (not finite): '
                            'refusing the trial')
    parts, at = [], 1
    for size in sizes.ctrl:
        parts.append(values[at:at + size].astype(float))
        at += size
    time = float(parts[4][0]) if parts[4].size else float('nan')
    if action == COMMIT_STATE:
        return Request(action, _EMPTY, _EMPTY, _EMPTY, _EMPTY, time)
    return Request(action, parts[0], parts[1], parts[2], parts[3], time)


def encode_reply(sizes: Sizes, values) -> bytes:
    """Return ``values`` (a reading, at most dataSize float64) padded to one message."""
    out = np.zeros(sizes.data_size)
    v = np.asarray(values, dtype=float).ravel()
    if v.size > sizes.data_size:
        raise ValueError(f'{v.size} values do not fit in dataSize {sizes.data_size}')
    out[:v.size] = v
    return out.astype('<f8').tobytes()


def encode_matrix(sizes: Sizes, matrix) -> bytes:
    """Return the n x n ``matrix`` in column order (as OpenSees' Matrix stores it), padded."""
    m = np.asarray(matrix, dtype=float)
    if m.shape != (sizes.n, sizes.n):
        raise ValueError(f'matrix of shape {m.shape}; the client has n = {sizes.n}')
    return encode_reply(sizes, m.ravel(order='F'))


def daq_values(sizes: Sizes, disp, vel, accel, force, time) -> np.ndarray:
    """Return the ``getDaqResponse`` values: the daq vectors the set-up asks for, in order."""
    parts = (disp, vel, accel, force, np.atleast_1d(time))
    return np.concatenate([np.asarray(p, dtype=float).ravel()[:size]
                           for p, size in zip(parts, sizes.daq, strict=True)])


def encode_request(sizes: Sizes, action: int, disp=(), vel=(), accel=(), force=(),
                   time=None) -> bytes:
    """Return one client message: ``action`` and, for a trial, its ctrl vectors (client side)."""
    out = np.zeros(sizes.data_size)
    out[0] = action
    if action in (SET_TRIAL_RESPONSE, COMMIT_STATE):
        at = 1
        parts = (disp, vel, accel, force, () if time is None else (time,))
        for part, size in zip(parts, sizes.ctrl, strict=True):
            p = np.asarray(part, dtype=float).ravel()
            out[at:at + min(size, p.size)] = p[:size]
            at += size
    return out.astype('<f8').tobytes()


def decode_reply(message: bytes, sizes: Sizes) -> dict:
    """Split a ``getDaqResponse`` reply into its daq vectors (client side)."""
    if len(message) != sizes.message_bytes:
        raise ProtocolError(f'reply of {len(message)} bytes; expected {sizes.message_bytes}')
    values = np.frombuffer(message, '<f8', count=sum(sizes.daq)).astype(float)
    out, at = {}, 0
    for name, size in zip(RESPONSES, sizes.daq, strict=True):
        out[name] = values[at:at + size]
        at += size
    return out


class Framer:
    """Cut a byte stream into the set-up and then whole messages of ``dataSize`` float64."""

    def __init__(self):
        """Start before the set-up."""
        self.sizes: Sizes | None = None
        self._buf = bytearray()

    @property
    def pending(self) -> int:
        """Bytes received that do not yet make a whole set-up or message."""
        return len(self._buf)

    def feed(self, data: bytes) -> list:
        """Add received bytes; return the whole units now complete (Sizes first, then bytes)."""
        self._buf += data
        out = []
        if self.sizes is None:
            if len(self._buf) < SETUP.size:
                return out
            self.sizes = Sizes.unpack(bytes(self._buf[:SETUP.size]))
            del self._buf[:SETUP.size]
            out.append(self.sizes)
        size = self.sizes.message_bytes
        while len(self._buf) >= size:
            out.append(bytes(self._buf[:size]))
            del self._buf[:size]
        return out

    def truncation(self) -> str:
        """Describe a stream that ended here ('' if it ended between messages)."""
        if not self._buf:
            return ''
        what = ('set-up', SETUP.size) if self.sizes is None else \
            ('message', self.sizes.message_bytes)
        return f'the client closed the connection after {len(self._buf)} of the ' \
               f'{what[1]} bytes of a {what[0]} (truncated)'
