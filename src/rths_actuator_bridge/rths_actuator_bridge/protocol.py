"""The servo-controller datagram protocol: layout, kinds, status and fault codes, channel names.

The reference description is ``docs/controller_protocol.md``; this module is
its executable form (no sockets, no plant).  Every datagram is little-endian:

version 1 (18-byte header)::

    '<4sBBHHQ'        magic b'RTHS', version 1, kind, n_channels, n_values, step
    n_values x '<f8'  values

version 2 (30-byte header; negotiated at ACTIVATE)::

    '<4sBBHHQIIHH'    magic, version 2, kind, n_channels, n_values, step,
                      session, sequence, status, fault
    n_values x '<f8'  values
    rest              UTF-8 text: the reply channel names (ACK, HEARTBEAT) or a fault message

Kinds: 1 COMMAND (bridge -> controller), 2 REPLY, 3 ACTIVATE, 4 DEACTIVATE,
5 ACK, 6 HEARTBEAT (version 2 only, either direction).
"""

from dataclasses import dataclass
import re
import struct

import numpy as np

MAGIC = b'RTHS'
VERSIONS = (1, 2)
HEADER_V1 = struct.Struct('<4sBBHHQ')
HEADER_V2 = struct.Struct('<4sBBHHQIIHH')
HEADERS = {1: HEADER_V1, 2: HEADER_V2}
COMMAND, REPLY, ACTIVATE, DEACTIVATE, ACK, HEARTBEAT = 1, 2, 3, 4, 5, 6
KIND_NAMES = {COMMAND: 'COMMAND', REPLY: 'REPLY', ACTIVATE: 'ACTIVATE',
              DEACTIVATE: 'DEACTIVATE', ACK: 'ACK', HEARTBEAT: 'HEARTBEAT'}
MAX_VALUES = 1024
#: Longest text of a version-2 datagram [bytes].
MAX_TEXT = 1024

#: Status bits of a version-2 datagram from the controller.
ST_ACTIVE = 0x1      # the controller takes COMMANDs (between ACTIVATE and DEACTIVATE)
ST_HOLDING = 0x2     # its own interlock holds the actuator or brings it to rest
ST_LIMITED = 0x4     # the COMMAND of this step broke the controller's limits: not applied
ST_FAULT = 0x8       # a fault (code in ``fault``, message in the text)

#: Fault codes of a version-2 datagram (0: none).
FAULTS = {0: 'none', 1: 'command limit', 2: 'channel count', 3: 'interlock',
          4: 'not active', 5: 'sampling rate', 6: 'bad request', 255: 'controller fault'}
F_NONE, F_LIMIT, F_CHANNELS, F_INTERLOCK, F_NOT_ACTIVE, F_RATE, F_REQUEST, F_OTHER = (
    0, 1, 2, 3, 4, 5, 6, 255)

#: Quantities a REPLY may carry, with their SI unit.  Others are allowed and ignored.
QUANTITIES = {'displacement': 'm', 'force': 'N', 'rel_disp': 'm', 'rel_vel': 'm/s',
              'table_accel': 'm/s^2'}
#: Quantities every channel of a REPLY must carry.
REQUIRED = ('displacement', 'force')
_NAME = re.compile(r'^([a-z][a-z0-9_]*)(?:\.(\d+))?$')


@dataclass
class Datagram:
    """One decoded datagram (version-1 datagrams have session, sequence, status, fault 0)."""

    kind: int
    step: int
    n_channels: int
    values: np.ndarray
    version: int = 1
    session: int = 0
    sequence: int = 0
    status: int = 0
    fault: int = 0
    text: str = ''

    @property
    def active(self) -> bool:
        """Return True if a version-2 sender says it takes COMMANDs (status bit ACTIVE)."""
        return bool(self.status & ST_ACTIVE)


def pack(kind: int, step: int, values=(), n_channels: int = 1, *, version: int = 1,
         session: int = 0, sequence: int = 0, status: int = 0, fault: int = 0,
         text: str = '') -> bytes:
    """Encode one datagram of ``version`` (text only in version 2)."""
    vals = np.asarray(values, '<f8').ravel()
    if version == 1:
        if text:
            raise ValueError('a version-1 datagram carries no text')
        return HEADER_V1.pack(MAGIC, 1, kind, n_channels, vals.size, step) + vals.tobytes()
    raw = text.encode('utf-8')
    if len(raw) > MAX_TEXT:
        raise ValueError(f'datagram text of {len(raw)} bytes is longer than {MAX_TEXT}')
    return (HEADER_V2.pack(MAGIC, 2, kind, n_channels, vals.size, step, session & 0xFFFFFFFF,
                           sequence & 0xFFFFFFFF, status, fault) + vals.tobytes() + raw)


def unpack(data: bytes) -> Datagram:
    """Decode one datagram; ValueError (saying what is wrong) if it is malformed."""
    if len(data) < HEADER_V1.size:
        raise ValueError(f'datagram of {len(data)} bytes is shorter than the header')
    if data[:4] != MAGIC:
        raise ValueError(f'bad magic {bytes(data[:4])!r}')
    version = data[4]
    if version not in HEADERS:
        raise ValueError(f'unknown version {version}')
    header = HEADERS[version]
    if len(data) < header.size:
        raise ValueError(f'version-{version} datagram of {len(data)} bytes is shorter than '
                         f'its {header.size}-byte header')
    fields = header.unpack_from(data)
    kind, n_ch, n_val, step = fields[2:6]
    if kind not in KIND_NAMES or (kind == HEARTBEAT and version == 1):
        raise ValueError(f'bad kind {kind}')
    if n_val > MAX_VALUES:
        raise ValueError(f'value count {n_val} > {MAX_VALUES}')
    end = header.size + 8 * n_val
    if len(data) < end or (version == 1 and len(data) != end):
        raise ValueError(f'datagram size {len(data)} does not hold {n_val} values')
    values = np.frombuffer(data, '<f8', count=n_val, offset=header.size).astype(float)
    if version == 1:
        return Datagram(kind, step, n_ch, values)
    if len(data) - end > MAX_TEXT:
        raise ValueError(f'datagram text longer than {MAX_TEXT} bytes')
    try:
        text = bytes(data[end:]).decode('utf-8')
    except UnicodeDecodeError:
        raise ValueError('datagram text is not UTF-8') from None
    session, sequence, status, fault = fields[6:]
    return Datagram(kind, step, n_ch, values, 2, session, sequence, status, fault, text)


def default_names(n_channels: int, quantities=REQUIRED) -> list:
    """Reply channel names: ``displacement, force`` for one channel, ``displacement.0, ...``."""
    if n_channels == 1:
        return list(quantities)
    return [f'{q}.{i}' for q in quantities for i in range(n_channels)]


def parse_names(text: str, n_channels: int) -> dict:
    """Map ``'name,name,...'`` to ``{(quantity, channel): index}``; ValueError if unusable.

    A name is ``QUANTITY`` (channel 0 of a one-channel controller) or
    ``QUANTITY.I`` (channel I, from 0).  Every channel needs ``displacement``
    and ``force``; names may not repeat; unknown quantities are kept (ignored
    by the bridge).
    """
    names = [n.strip() for n in str(text).split(',') if n.strip()]
    index = {}
    for i, name in enumerate(names):
        m = _NAME.match(name)
        if not m:
            raise ValueError(f'reply channel name {name!r} is not QUANTITY or QUANTITY.CHANNEL '
                             '(lower case, e.g. displacement or force.1)')
        quantity, channel = m.group(1), int(m.group(2) or 0)
        if m.group(2) is None and n_channels > 1:
            raise ValueError(f'reply channel name {name!r} needs a channel number '
                             f'({name}.0 .. {name}.{n_channels - 1}): there are {n_channels} '
                             'channels')
        if channel >= n_channels:
            raise ValueError(f'reply channel {name!r}: channel {channel} >= {n_channels} '
                             'channel(s)')
        if (quantity, channel) in index:
            raise ValueError(f'reply channel {name!r} appears twice')
        index[(quantity, channel)] = i
    missing = [f'{q}.{c}' if n_channels > 1 else q for q in REQUIRED for c in range(n_channels)
               if (q, c) not in index]
    if missing:
        raise ValueError(f'reply channels {", ".join(missing)} are missing (every channel '
                         f'needs {" and ".join(REQUIRED)}); names given: {", ".join(names)}')
    return index


def describe(d: Datagram) -> str:
    """One line describing a datagram (for logs and the conformance report)."""
    out = f'v{d.version} {KIND_NAMES.get(d.kind, d.kind)} step {d.step} ' \
          f'{d.n_channels} ch {d.values.size} values'
    if d.version == 2:
        out += f' session {d.session:#010x} seq {d.sequence} status {d.status:#x}'
        if d.fault:
            out += f' fault {d.fault} ({FAULTS.get(d.fault, "?")})'
        if d.text:
            out += f' text {d.text!r}'
    return out


def fault_text(d: Datagram) -> str:
    """Return the controller's fault of a version-2 datagram as text ('' when none)."""
    if d.version != 2 or not (d.fault or d.status & (ST_FAULT | ST_LIMITED)):
        return ''
    name = FAULTS.get(d.fault, f'code {d.fault}')
    return f'{name}: {d.text}' if d.text else name
