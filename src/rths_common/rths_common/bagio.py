"""Reading and writing the project's rosbag2 bags with ``rosbags`` (no rosbag2 needed).

Bags use the rosbag2 MCAP storage (the default of ``ros2 bag`` since Iron;
``storage='sqlite3'`` writes the older sqlite3 storage), format version 9, so
``ros2 bag info``, ``ros2 bag play`` and Foxglove read them in a lab.  Every
reader here reads both.  The custom types are registered in a ``rosbags``
typestore from the installed ``rths_msgs`` .msg files.

Crash safety: :class:`BagWriter` commits every ``commit_period_s``
(:func:`rths_common.bagstore.commit`: the sqlite3 transaction, or the MCAP chunk
flushed to the file); if the recording process is killed (SIGKILL) the
messages committed so far are on disk but ``metadata.yaml`` is missing (and an
MCAP file its summary and footer).  :func:`reindex` rebuilds it from the data
file (like ``ros2 bag reindex``), closing a cut MCAP file first, and
:func:`open_reader` does so automatically, so a crashed run's bag stays
readable.

Damaged bags: :func:`open_reader` also closes an MCAP file cut short under a
``metadata.yaml`` that was kept, and rebuilds a ``metadata.yaml`` that is
truncated or not valid (the old one is kept as ``metadata.yaml.damaged``).
Bytes damaged inside the data are found when they are read:
:func:`read_messages` then raises :class:`BagDamaged` (a ValueError) naming
the bag and how many messages before the damage were read, and :func:`info`
counts the messages that can be read (``damaged`` says why the rest cannot).
"""

from functools import lru_cache
import os
from pathlib import Path
import sqlite3
import struct
import time

import numpy as np
import yaml

from rths_common import bagstore, runinfo, topics


def _msg_dir() -> Path:
    """Directory holding the rths_msgs .msg files (installed share dir, else the source tree)."""
    try:
        # lazy: optional: tried here, refused with a clear message when missing
        from ament_index_python.packages import get_package_share_directory
        path = Path(get_package_share_directory('rths_msgs')) / 'msg'
        if path.is_dir():
            return path
    except Exception:  # noqa: BLE001 - ament index not available: fall back to the source tree
        pass
    root = Path(os.environ.get('RTHS_ROOT', Path(__file__).resolve().parents[3]))
    path = root / 'src' / 'rths_msgs' / 'msg'
    if not path.is_dir():
        raise OSError('cannot find the rths_msgs .msg files (looked in the ament index and '
                      f'{path}); '
                      "run 'make setup' and 'source env.sh'")
    return path


@lru_cache(maxsize=1)
def typestore():
    """Return a ROS 2 Jazzy typestore with the rths_msgs types registered."""
    # lazy: start-up cost: rosbags (~0.2 s), which this module needs only here
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for path in sorted(_msg_dir().glob('*.msg')):
        types.update(get_types_from_msg(path.read_text(), f'rths_msgs/msg/{path.stem}'))
    store.register(types)
    return store


class BagWriter:
    """Write serialized (CDR) messages to a new rosbag2 bag, committing periodically.

    ``storage`` is ``'mcap'`` (default) or ``'sqlite3'``.

    ``topic_types`` maps topic name to message type (e.g. ``topics.LOOP_TOPICS``).
    Messages are written with :meth:`write` as raw CDR bytes (what an rclpy
    subscription with ``raw=True`` delivers) or with :meth:`write_msg` as
    rosbags message objects.
    """

    def __init__(self, path, topic_types=None, commit_period_s: float = 0.1, run_info=None,
                 storage: str = bagstore.DEFAULT_STORAGE):
        # lazy: start-up cost: rosbags (~0.2 s), which this module needs only here
        from rosbags.interfaces import Connection
        from rosbags.rosbag2 import Writer

        self.storage = bagstore.check_storage(storage)
        self.path = Path(path)
        if self.path.exists():
            raise OSError(f'bag {self.path} already exists; choose a new --bag directory '
                          'or delete the old one')
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._writer: Writer | None = Writer(self.path, version=9,
                                             storage_plugin=bagstore.plugin(storage))
        self._writer.open()
        self._storage = self._writer.storage
        if self.storage == 'mcap':
            bagstore.checksum_chunks(self._storage)   # every chunk carries its CRC-32
        self.run_info = {str(k): str(v) for k, v in (run_info or {}).items()}
        for key, value in self.run_info.items():
            self._writer.set_custom_data(key, value)
        if self.run_info:  # also beside the database, so a crashed recording keeps it
            (self.path / RUN_INFO_FILE).write_text(yaml.safe_dump(self.run_info))
        self._connections: dict[str, Connection] = {}
        self._commit_period_s = commit_period_s
        self._last_commit = time.monotonic()
        self.count = 0
        for topic, msgtype in (topic_types or topics.LOOP_TOPICS).items():
            self.add_topic(topic, msgtype)
        self.commit()

    def _open_writer(self):
        if self._writer is None:
            raise OSError(f'bag {self.path} is closed')
        return self._writer

    def add_topic(self, topic: str, msgtype: str):
        """Register ``topic`` with ``msgtype`` (must be known to :func:`typestore`)."""
        self._connections[topic] = self._open_writer().add_connection(
            topic, msgtype, typestore=typestore())

    def write(self, topic: str, timestamp_ns: int, cdr: bytes):
        """Append one serialized message; commit if the commit period has passed."""
        self._open_writer().write(self._connections[topic], int(timestamp_ns), cdr)
        self.count += 1
        now = time.monotonic()
        if now - self._last_commit >= self._commit_period_s:
            self.commit()
            self._last_commit = now

    def write_msg(self, topic: str, timestamp_ns: int, msg):
        """Serialize a rosbags message object and append it."""
        conn = self._connections[topic]
        self.write(topic, timestamp_ns, typestore().serialize_cdr(msg, conn.msgtype))

    def commit(self):
        """Make everything written so far durable (survives a SIGKILL of this process)."""
        # rosbags commits (sqlite3) or writes the pending chunk (MCAP) only on close;
        # doing it early is what makes a killed recording recoverable by reindex().
        bagstore.commit(self._storage, self.storage)

    def close(self):
        """Finish the bag: commit and write metadata.yaml."""
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


#: Side file of a bag holding its run information (also in metadata custom_data).
RUN_INFO_FILE = 'rths_run.yaml'


def bag_dir(bag) -> Path:
    """Return the bag directory of ``bag`` (itself, or the one holding its .mcap/.db3 file).

    A results directory of ``rths run`` given instead of its bag (a directory holding
    no bag files but bags below it) is refused with a ValueError naming those bags.
    """
    bag = Path(bag)
    if bag.is_file() and bag.suffix in ('.mcap', '.db3'):
        return bag.parent
    if bag.is_dir() and not _holds_bag_files(bag):
        inner = sorted(p.parent for pattern in ('*/metadata.yaml', '*/*/metadata.yaml')
                       for p in bag.glob(pattern))
        if inner:
            raise ValueError(f'{bag} is a results directory, not a bag; pass one of its bags: '
                             + ', '.join(str(p) for p in inner)
                             + (f' (the RTHS run: {bag / "rths" / "bag"})'
                                if bag / 'rths' / 'bag' in inner else ''))
    return bag


def _holds_bag_files(path: Path) -> bool:
    return (path / 'metadata.yaml').exists() or any(
        p.suffix in ('.mcap', '.db3') for p in path.iterdir())


def run_info(bag) -> dict:
    """Run information of a bag (``fs_hz``, ``mode``, ...): custom_data, else the side file.

    A damaged ``metadata.yaml`` is rebuilt first, as :func:`open_reader` does.
    """
    bag = bag_dir(bag)
    if (bag / 'metadata.yaml').exists():
        try:
            info = metadata(bag)
        except ValueError:
            open_reader(bag).close()    # rebuilds it (the old one kept), or BagDamaged
            info = metadata(bag)
        custom = info.get('custom_data')
        if custom:
            if not isinstance(custom, dict):
                raise ValueError(f'{bag / "metadata.yaml"}: custom_data is not a mapping; '
                                 "rebuild the file with 'rths bag reindex'")
            return dict(custom)
    side = bag / RUN_INFO_FILE
    if not side.exists():
        return {}
    try:
        data = yaml.safe_load(side.read_text())
    except yaml.YAMLError as err:
        raise ValueError(f'{side}: not valid YAML ({_first_line(err)})') from None
    if data is not None and not isinstance(data, dict):
        raise ValueError(f'{side}: must be a mapping of run information, '
                         f'got {type(data).__name__}')
    return data or {}


def _first_line(err) -> str:
    return str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__


def metadata(bag) -> dict:
    """Return ``rosbag2_bagfile_information`` of a bag's metadata.yaml, checked to be a mapping.

    A file that is not YAML, not a mapping or lacks that key raises ValueError
    naming the file and the fix (``rths bag reindex`` rebuilds it from the data file).
    """
    meta = bag_dir(bag) / 'metadata.yaml'
    fix = f"rebuild it with 'rths bag reindex {bag_dir(bag)}'"
    try:
        data = yaml.safe_load(meta.read_text())
    except yaml.YAMLError as err:
        raise ValueError(f'{meta}: not valid YAML ({_first_line(err)}); {fix}') from None
    except UnicodeDecodeError:
        raise ValueError(f'{meta}: not a text file; {fix}') from None
    if not isinstance(data, dict):
        raise ValueError(f'{meta}: must be a mapping with rosbag2_bagfile_information, got '
                         f'{type(data).__name__}; {fix}')
    info = data.get('rosbag2_bagfile_information')
    if not isinstance(info, dict):
        raise ValueError(f'{meta}: rosbag2_bagfile_information is missing or not a mapping; '
                         f'{fix}')
    return info


def reindex(bag) -> Path:
    """Rebuild ``metadata.yaml`` of a bag from its data file; return its path.

    An MCAP file a killed recorder left without its footer is closed first
    (:func:`rths_common.bagstore.repair_mcap`).
    """
    bag = bag_dir(bag)
    if bagstore.storage_of(bag) == 'mcap':
        return _reindex_mcap(bag)
    return _reindex_sqlite3(bag)


def _write_metadata(bag: Path, storage: str, data_file: Path, topic_rows, t0: int, t1: int):
    """Write ``metadata.yaml`` (format 9); ``topic_rows``: (name, type, fmt, qos, hash, count)."""
    total = sum(row[-1] for row in topic_rows)
    info = {
        'version': 9,
        'storage_identifier': storage,
        'relative_file_paths': [data_file.name],
        'duration': {'nanoseconds': t1 - t0},
        'starting_time': {'nanoseconds_since_epoch': t0},
        'message_count': total,
        'topics_with_message_count': [
            {'topic_metadata': {'name': name, 'type': msgtype,
                                'serialization_format': fmt,
                                'offered_qos_profiles': qos,
                                'type_description_hash': digest},
             'message_count': count}
            for name, msgtype, fmt, qos, digest, count in topic_rows],
        'compression_format': '',
        'compression_mode': '',
        'files': [{'path': data_file.name, 'starting_time': {'nanoseconds_since_epoch': t0},
                   'duration': {'nanoseconds': t1 - t0}, 'message_count': total}],
        'custom_data': dict(run_info(bag), reindexed='true'),
        'ros_distro': 'rosbags',
    }
    meta = bag / 'metadata.yaml'
    tmp = meta.with_suffix('.yaml.tmp')
    tmp.write_text(yaml.safe_dump({'rosbag2_bagfile_information': info}, sort_keys=False))
    tmp.replace(meta)
    return meta


def _reindex_mcap(bag: Path) -> Path:
    path = bagstore.data_file(bag)
    bagstore.repair_mcap(path)
    scan = bagstore.mcap_topics(path)
    rows: list[tuple] = [(name, msgtype, fmt, [], digest, count)
                         for name, msgtype, fmt, digest, count in scan['topics']]
    return _write_metadata(bag, 'mcap', path, rows, scan['start_ns'], scan['end_ns'])


def _reindex_sqlite3(bag: Path) -> Path:
    db = bagstore.data_file(bag)
    # Not read-only: a killed writer leaves a hot journal that sqlite must roll back first.
    conn = sqlite3.connect(db)
    try:
        rows = conn.execute('SELECT id, name, type, serialization_format, offered_qos_profiles, '
                            'type_description_hash FROM topics ORDER BY id').fetchall()
        counts = dict(conn.execute('SELECT topic_id, COUNT(*) FROM messages GROUP BY topic_id'))
        t0, t1 = conn.execute('SELECT MIN(timestamp), MAX(timestamp) FROM messages').fetchone()
    finally:
        conn.close()
    t0 = t0 or 0
    return _write_metadata(bag, 'sqlite3', db,
                           [(name, msgtype, fmt, qos, digest, counts.get(tid, 0))
                            for tid, name, msgtype, fmt, qos, digest in rows], t0, t1 or t0)


class BagDamaged(ValueError):
    """Data of a bag that cannot be read (the one-line message names the bag and the fix)."""


#: What a damaged bag raises inside rosbags and the decoders it uses.
_READ_ERRORS = (KeyError, IndexError, TypeError, AttributeError, EOFError, UnicodeDecodeError,
                OverflowError, MemoryError, struct.error, sqlite3.DatabaseError)


def _reader_errors():
    # lazy: start-up cost: rosbags (~0.2 s), which this module needs only to read
    from rosbags.rosbag2.errors import ReaderError
    from rosbags.serde import SerdeError
    try:   # rosbags reads sqlite3 bags with apsw when it is installed
        # lazy: optional, as in rosbags
        from apsw import Error as ApswError
    except ImportError:
        return (ReaderError, SerdeError, *_READ_ERRORS)
    return (ReaderError, SerdeError, ApswError, *_READ_ERRORS)


def open_reader(bag):
    """Open a bag for reading with rosbags, repairing what a crash or damage left.

    No or damaged ``metadata.yaml``, or an MCAP file without its end: closed and
    reindexed first (module doc); BagDamaged if it still cannot be opened.
    """
    # lazy: start-up cost: rosbags (~0.2 s), which this module needs only here
    from rosbags.rosbag2 import Reader

    bag = bag_dir(bag)
    if not bag.is_dir():
        raise OSError(f'bag directory {bag} does not exist')
    meta = bag / 'metadata.yaml'
    if not meta.exists():
        _reindex_or_refuse(bag)
    elif bagstore.storage_of(bag) == 'mcap' and not bagstore.is_complete(bagstore.data_file(bag)):
        _reindex_or_refuse(bag)         # cut short under a metadata.yaml that was kept
    errors = _reader_errors()
    for attempt in range(2):
        reader = Reader(bag)
        try:
            reader.open()
            for conn in reader.connections:   # metadata.yaml's own fields, read exactly
                if not (isinstance(conn.topic, str) and isinstance(conn.msgtype, str)):
                    raise ValueError(f'topic {conn.topic!r} of type {conn.msgtype!r} is not '
                                     'a name')
            return reader
        except (*errors, ValueError) as err:
            if attempt:
                raise BagDamaged(f'{bag}: the bag cannot be read even after rebuilding its '
                                 f'metadata ({str(err)[:120]})') from None
            meta.replace(meta.with_name('metadata.yaml.damaged'))
            _reindex_or_refuse(bag)
    raise AssertionError('unreachable')


def _reindex_or_refuse(bag: Path) -> None:
    """:func:`reindex`, or BagDamaged if the data file itself cannot be scanned."""
    try:
        reindex(bag)
    except (*_reader_errors(), ValueError) as err:
        raise BagDamaged(f'{bag}: its data file is damaged where its records are indexed '
                         f'({str(err)[:120]}); no message can be read') from None


def info(bag) -> dict:
    """Storage, topics (type, count), total count, start time and duration of a bag.

    The counts are of the messages that can be read (every one is read): a
    damaged bag says so in ``damaged`` (None when whole).
    """
    reader = open_reader(bag)
    try:
        out = {
            'path': str(bag),
            'storage': bagstore.storage_of(bag_dir(bag)),
            'duration_s': reader.duration * 1e-9 if reader.message_count else 0.0,
            'start_time_s': reader.start_time * 1e-9 if reader.message_count else 0.0,
            'message_count': reader.message_count,
            'topics': {c.topic: {'type': c.msgtype, 'count': 0} for c in reader.connections},
            'damaged': None,
        }
        try:   # the reader just opened: one open (one metadata parse) per call
            for topic, _, _ in _messages(reader, bag, None):
                out['topics'][topic]['count'] += 1
        except BagDamaged as err:
            out['damaged'] = str(err)
    finally:
        reader.close()
    out['message_count'] = sum(t['count'] for t in out['topics'].values())
    return out


def read_messages(bag, topic_names=None):
    """Yield ``(topic, timestamp_ns, msg)`` in time order, deserialized with :func:`typestore`."""
    reader = open_reader(bag)
    try:
        yield from _messages(reader, bag, topic_names)
    finally:
        reader.close()


def _messages(reader, bag, topic_names):
    """:func:`read_messages` from an open ``reader``."""
    store = typestore()
    conns = [c for c in reader.connections if topic_names is None or c.topic in topic_names]
    for conn, timestamp, raw in raw_messages(reader, bag, conns):
        try:
            msg = store.deserialize_cdr(raw, conn.msgtype)
        except (*_reader_errors(), ValueError) as err:
            raise BagDamaged(f'{bag}: a damaged {conn.topic} message ({str(err)[:120]}); '
                             'the bag cannot be read past it') from None
        yield conn.topic, timestamp, msg


def raw_messages(reader, bag, connections):
    """Yield ``reader.messages(connections=...)``; damaged data raises :class:`BagDamaged`.

    No connections yield nothing (rosbags reads every connection when given none).
    """
    if not connections:
        return
    count = 0
    messages = reader.messages(connections=connections)
    while True:
        try:
            item = next(messages)
        except StopIteration:
            return
        except (*_reader_errors(), ValueError) as err:
            raise BagDamaged(f'{bag}: damaged data after {count} readable message(s) '
                             f'({str(err)[:120]}); the bag cannot be read past it') from None
        count += 1
        yield item


def read_topic(bag, topic: str) -> list:
    """All messages of one topic, in order, as ``(timestamp_ns, msg)`` pairs."""
    return [(t, m) for _, t, m in read_messages(bag, [topic])]


def step_arrays(bag, topic: str, fields) -> dict:
    """``{'step': int array, field: 2-D float array (steps x channels), ...}`` of one topic.

    A message whose array is shorter than the widest one (e.g. a bridge step
    that applied nothing) is padded with NaN.
    """
    steps: list[int] = []
    values: dict[str, list] = {f: [] for f in fields}
    for _, msg in read_topic(bag, topic):
        steps.append(msg.step)
        for f in fields:
            values[f].append(np.asarray(getattr(msg, f), dtype=float))
    out = {'step': np.asarray(steps, dtype=np.int64)}
    for f in fields:
        width = max((v.size for v in values[f]), default=0)
        table = np.full((len(values[f]), width), np.nan)
        for i, v in enumerate(values[f]):
            table[i, :v.size] = v
        out[f] = table
    return out


def sampling_rate(bag) -> float:
    """Return the loop rate ``fs_hz`` a bag was recorded at (from its run information)."""
    info = run_info(bag)
    try:
        return float(info['fs_hz'])
    except (KeyError, ValueError):
        raise ValueError(f'{bag}: the bag has no fs_hz in its run information '
                         f'(metadata custom_data or {RUN_INFO_FILE}); record it with '
                         "'rths launch' or 'rths run'") from None


def delay_steps(bag) -> int:
    """Return the bridge's ``command_delay_steps`` D of a run (0 if the run info lacks it)."""
    return int(runinfo.section(run_info(bag), 'bridge').get('command_delay_steps', 0) or 0)


def read_identification(bag, loop: bool = True):
    """``(time [s], command [m], measured [m])`` of channel 0 from a bag's measurements.

    ``command`` is what the bridge wrote to the actuator (``Measurement.applied``),
    ``measured`` the measured actuator displacement; time is ``step / fs_hz``.
    Steps the bridge did not apply (empty arrays) are dropped.

    ``loop=True`` (identification for the compensator): the plant as the loop
    sees it, from the command of step k to the measurement of step k.  With a
    bridge delay line of D steps (``command_delay_steps``) the command of step
    k was written at tick k + D, so the pairs are (applied[k + D], measured[k])
    and the identified plant includes the D-step delay.  ``loop=False``: the
    actuator alone (applied and measured at the same tick).
    """
    t, command, measured = read_identification_channels(bag, loop, channels=1)
    return t, command[:, 0], measured[:, 0]


def read_identification_channels(bag, loop: bool = True, channels: int | None = None):
    """``(time [s], commands [m], measured [m])``, one column per actuator, of a bag.

    As :func:`read_identification` (the same pairing of command and measurement), for
    the first ``channels`` actuators (default: every one the bag holds); steps where any
    of them is missing are dropped.  ValueError if the bag holds fewer than ``channels``.
    """
    fs = sampling_rate(bag)
    data = step_arrays(bag, topics.MEASUREMENT, ('applied', 'displacement'))
    if data['step'].size == 0:
        raise ValueError(f'{bag}: no {topics.MEASUREMENT} messages; is this an rths run bag?')
    width = min(data['applied'].shape[1], data['displacement'].shape[1])
    n = width if channels is None else int(channels)
    if width < n:
        raise ValueError(f'{bag}: the bag holds {width} actuator channel(s), not {n}; give '
                         f'--channels {width}')
    step = data['step']
    command, measured = data['applied'][:, :n], data['displacement'][:, :n]
    shift = delay_steps(bag) if loop else 0
    if shift:
        row = {k: i for i, k in enumerate(step.tolist())}
        command = np.array([command[row[k + shift]] if k + shift in row
                            else np.full(n, np.nan) for k in step.tolist()]).reshape(-1, n)
    ok = np.all(np.isfinite(command), axis=1) & np.all(np.isfinite(measured), axis=1)
    return step[ok] / fs, command[ok], measured[ok]


def read_specimen(bag, frame_mass_kg: float) -> dict:
    """``time``, ``base_accel``, ``rel_disp`` and ``force`` of the DTM specimen in a run bag.

    ``base_accel`` is the table (= DTM frame) acceleration and ``rel_disp`` the
    DTM relative displacement, both from ``/rths/specimen``; ``force`` is the
    force the damper exerts on its frame, ``m_frame * a_table - R`` with ``R``
    the measured restoring force (the load cells also carry the frame's
    inertia).  ``m_frame`` is the bridge's ``frame_mass_kg`` of the run, else
    ``frame_mass_kg``.  Steps with a non-finite value are dropped.
    """
    fs = sampling_rate(bag)
    spec = step_arrays(bag, topics.SPECIMEN, ('table_accel', 'rel_disp'))
    if spec['step'].size == 0:
        raise ValueError(f'{bag}: no {topics.SPECIMEN} messages (the bridge publishes them in '
                         'lock-step mode, or with publish_specimen: true)')
    meas = step_arrays(bag, topics.MEASUREMENT, ('force',))
    force_by_step = dict(zip(meas['step'].tolist(), meas['force'][:, 0], strict=True))
    steps = np.array([k for k in spec['step'] if k in force_by_step], dtype=np.int64)
    index = {k: i for i, k in enumerate(spec['step'].tolist())}
    rows = [index[k] for k in steps]
    frame = runinfo.section(run_info(bag), 'bridge').get('frame_mass_kg')
    frame = frame_mass_kg if frame in (None, '') or not np.isfinite(float(frame)) else float(frame)
    accel = spec['table_accel'][rows, 0]
    restoring = np.array([force_by_step[k] for k in steps])
    ok = np.isfinite(accel) & np.isfinite(restoring) & np.isfinite(spec['rel_disp'][rows, 0])
    return {'time': steps[ok] / fs, 'base_accel': accel[ok],
            'rel_disp': spec['rel_disp'][rows, 0][ok],
            'force': (frame * accel - restoring)[ok]}
