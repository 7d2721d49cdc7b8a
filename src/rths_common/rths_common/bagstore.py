"""Storage back ends of the project's rosbag2 bags: MCAP (the default) and sqlite3.

``rosbags`` writes both.  What it does not do, and this module adds:

* durable commits while recording (:func:`commit`): sqlite3 commits its
  transaction; MCAP closes the pending chunk (a complete, self-describing
  record) and flushes it to the file, so a SIGKILLed recorder leaves every
  committed message on disk;
* recovery of an MCAP file that a killed writer left without its summary,
  footer and closing magic (:func:`repair_mcap`): the file is cut after its last
  complete record and closed with a DataEnd record and a footer without a
  summary, which every MCAP reader (rosbags, the ``mcap`` library, Foxglove)
  reads by scanning;
* the ``metadata.yaml`` topic table of such a file (:func:`mcap_topics`), for
  ``bagio.reindex``;
* the messages per topic already committed to a bag that is still being
  written (:func:`committed_counts`), read without touching the file;
* a CRC-32 of every MCAP chunk (:func:`checksum_chunks`: rosbags writes 0, "not
  computed") and the check of a whole data file (:func:`check_integrity`: every
  MCAP chunk against its CRC; sqlite3 has no per-row checksum, its pages and
  indexes are checked with ``PRAGMA integrity_check``).
"""

import os
from pathlib import Path
import sqlite3
import struct
import zlib

#: Storage identifiers of ``metadata.yaml`` that rths writes and reads.
STORAGES = ('mcap', 'sqlite3')
#: Storage of every bag rths writes unless told otherwise (``--storage``).
DEFAULT_STORAGE = 'mcap'

MAGIC = b'\x89MCAP0\r\n'
_OP_HEADER, _OP_FOOTER, _OP_DATA_END = 0x01, 0x02, 0x0F
_RECORD = struct.Struct('<BQ')          # opcode, content length
_FOOTER_LEN = 20                        # summary_start, summary_offset_start, summary_crc


def check_storage(storage: str) -> str:
    """Return ``storage`` if rths can write it, else raise ValueError naming the choices."""
    if storage not in STORAGES:
        raise ValueError(f'storage {storage!r}: use one of {", ".join(STORAGES)} '
                         f'(default {DEFAULT_STORAGE})')
    return storage


def plugin(storage: str):
    """Return the ``rosbags`` StoragePlugin of a storage identifier."""
    # lazy: start-up cost: rosbags (~0.2 s), which this module needs only here
    from rosbags.rosbag2 import StoragePlugin

    return {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}[check_storage(storage)]


def commit(storage_writer, storage: str):
    """Make everything written so far durable against a SIGKILL of the writing process."""
    if storage == 'sqlite3':
        # rosbags' sqlite3 storage commits only on close
        storage_writer.conn.commit()
        return
    if storage_writer.chunk.msgs:        # rosbags keeps the pending chunk in memory
        storage_writer.close_chunk()
    storage_writer.bio.flush()


#: Offset of the CRC-32 of the uncompressed records in a Chunk record (after the record
#: head: message start time, message end time, uncompressed size).
_CHUNK_CRC_AT = _RECORD.size + 24


def checksum_chunks(storage_writer) -> None:
    """Make a rosbags MCAP storage writer store the CRC-32 of every chunk it closes.

    rosbags writes 0 ("not computed"); the CRC is of the chunk's uncompressed
    records, as the MCAP specification defines it, so every reader (rosbags,
    the ``mcap`` library, :func:`check_integrity`) checks it.
    """
    close = storage_writer.close_chunk

    def close_chunk():
        crc = zlib.crc32(storage_writer.chunk.bio.getbuffer())
        bio = storage_writer.bio
        start = bio.tell()
        close()
        end = bio.tell()
        bio.seek(start + _CHUNK_CRC_AT)
        bio.write(struct.pack('<I', crc))
        bio.seek(end)

    storage_writer.close_chunk = close_chunk


def check_integrity(bag) -> dict:
    """Check the data file of a bag; return what was checked and what is wrong.

    MCAP: ``{'storage', 'check', 'chunks', 'chunks_checked', 'chunks_without_crc',
    'bad_chunks': [offset, ...], 'closed': bool, 'tail_bytes'}`` -- every chunk
    is decompressed and its CRC-32 compared (a chunk written with CRC 0, by an
    older rths or another writer, cannot be checked and is counted as such);
    ``closed`` is False for a file a killed writer left without its footer,
    ``tail_bytes`` the bytes after its last complete record (a chunk cut by
    the kill). sqlite3: ``{'storage', 'check', 'result'}``, the result of
    ``PRAGMA integrity_check`` ('ok' when the database is sound; rosbag2's
    sqlite3 storage has no per-message checksum).  ``'ok'`` sums it up.
    """
    bag = Path(bag)
    path = data_file(bag)
    if storage_of(bag) == 'sqlite3':
        try:
            conn = sqlite3.connect(f'file:{path}?mode=ro', uri=True, timeout=5.0)
            try:
                result = '; '.join(r[0] for r in conn.execute('PRAGMA integrity_check'))
            finally:
                conn.close()
        except sqlite3.Error as err:
            result = f'not a readable database ({err})'
        return {'storage': 'sqlite3', 'check': 'PRAGMA integrity_check (no per-message '
                'checksum in the sqlite3 storage)', 'result': result, 'ok': result == 'ok'}
    out: dict = {'storage': 'mcap', 'check': 'CRC-32 of every chunk', 'chunks': 0,
                 'chunks_checked': 0, 'chunks_without_crc': 0, 'bad_chunks': [],
                 'closed': is_complete(path), 'tail_bytes': 0}
    size = path.stat().st_size
    with path.open('rb') as handle:
        if handle.read(len(MAGIC)) != MAGIC:
            out.update(bad_chunks=[0], ok=False)
            return out
        pos = len(MAGIC)
        while True:
            head = handle.read(_RECORD.size)
            if len(head) < _RECORD.size:
                break
            opcode, length = _RECORD.unpack(head)
            if opcode in (_OP_DATA_END, _OP_FOOTER) or pos + _RECORD.size + length > size:
                break
            content = handle.read(length)
            if opcode == _OP_CHUNK:
                out['chunks'] += 1
                _check_chunk(content, pos, out)
            pos += _RECORD.size + length
        if not out['closed']:
            out['tail_bytes'] = size - pos
    out['ok'] = not out['bad_chunks'] and out['closed']
    return out


def _check_chunk(content: bytes, pos: int, out: dict) -> None:
    """Compare one chunk's records with its CRC-32 (module doc); note the result in ``out``."""
    try:
        (crc,) = struct.unpack_from('<I', content, 24)
        records = _chunk_records(content)
        (size,) = struct.unpack_from('<Q', content, 16)
    except (struct.error, ValueError, ImportError, RuntimeError) as err:
        out['bad_chunks'].append(pos)
        out.setdefault('errors', []).append(f'chunk at byte {pos}: {err}')
        return
    if len(records) != size:
        out['bad_chunks'].append(pos)
        return
    if not crc:
        out['chunks_without_crc'] += 1
        return
    out['chunks_checked'] += 1
    if zlib.crc32(records) != crc:
        out['bad_chunks'].append(pos)


def storage_of(bag) -> str:
    """Return the storage of a bag directory, from its data files (``*.mcap`` or ``*.db3``)."""
    bag = Path(bag)
    if any(bag.glob('*.mcap')):
        return 'mcap'
    if any(bag.glob('*.db3')):
        return 'sqlite3'
    raise OSError(f'{bag} is not a rosbag2 bag (no .mcap or .db3 file inside)')


def data_file(bag) -> Path:
    """Return the one data file of a bag (rths writes one file per bag)."""
    bag = Path(bag)
    files = sorted(bag.glob('*.mcap' if storage_of(bag) == 'mcap' else '*.db3'))
    return files[0]


def _records_end(handle, size: int) -> int:
    """Offset just past the last complete top-level record after the header (0 if none)."""
    handle.seek(len(MAGIC))
    end = 0
    while True:
        pos = handle.tell()
        head = handle.read(_RECORD.size)
        if len(head) < _RECORD.size:
            return end
        opcode, length = _RECORD.unpack(head)
        if opcode in (_OP_DATA_END, _OP_FOOTER) or pos + _RECORD.size + length > size:
            return end
        handle.seek(length, os.SEEK_CUR)
        end = handle.tell()


def is_complete(path) -> bool:
    """Return True if an MCAP file ends with its footer and closing magic."""
    path = Path(path)
    if path.stat().st_size < 2 * len(MAGIC) + _RECORD.size + _FOOTER_LEN:
        return False
    with path.open('rb') as handle:
        handle.seek(-(len(MAGIC) + _RECORD.size + _FOOTER_LEN), os.SEEK_END)
        tail = handle.read()
    opcode, length = _RECORD.unpack(tail[:_RECORD.size])
    return tail.endswith(MAGIC) and opcode == _OP_FOOTER and length == _FOOTER_LEN


def repair_mcap(path) -> bool:
    """Close an MCAP file a killed writer left open; return True if it was repaired.

    The file is cut after its last complete record (a chunk half-written when
    the process died is dropped) and closed with DataEnd, a footer without a
    summary and the magic.  A complete file is left untouched.
    """
    path = Path(path)
    if is_complete(path):
        return False
    size = path.stat().st_size
    with path.open('r+b') as handle:
        if handle.read(len(MAGIC)) != MAGIC:
            raise OSError(f'{path} is not an MCAP file (bad magic)')
        end = _records_end(handle, size)
        if not end:
            raise OSError(f'{path}: no complete MCAP record; the recording wrote nothing')
        handle.seek(end)
        handle.truncate()
        handle.write(_RECORD.pack(_OP_DATA_END, 4) + struct.pack('<I', 0))
        handle.write(_RECORD.pack(_OP_FOOTER, _FOOTER_LEN) + struct.pack('<QQI', 0, 0, 0))
        handle.write(MAGIC)
    return True


def mcap_topics(path) -> dict:
    """Topic table and time span of a (complete or repaired) MCAP file.

    Returns ``{'topics': [(name, type, serialization_format, type_description_hash,
    count), ...], 'start_ns', 'end_ns', 'count'}``; the counts come from
    rosbags' scan of the file (its summary, else its records).
    """
    # lazy: start-up cost: rosbags (~0.2 s), which this module needs only here
    from rosbags.interfaces import ConnectionExtRosbag2
    from rosbags.rosbag2.storage_mcap import McapReader

    reader = McapReader(Path(path))
    reader.open()
    try:
        stats = reader.statistics
        topics = [(c.topic, c.msgtype, c.ext.serialization_format
                   if isinstance(c.ext, ConnectionExtRosbag2) else 'cdr', c.digest, c.msgcount)
                  for c in reader.connections]
        count = int(stats.message_count) if stats else 0
        return {'topics': topics, 'count': count,
                'start_ns': int(stats.start_time) if stats and count else 0,
                'end_ns': int(stats.end_time) if stats and count else 0}
    finally:
        reader.close()


_OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK = 0x04, 0x05, 0x06


def _channel_topic(content: bytes) -> tuple:
    """Return ``(channel id, topic)`` of a Channel record's content."""
    (cid,) = struct.unpack_from('<H', content, 0)
    (n,) = struct.unpack_from('<I', content, 4)
    return cid, content[8:8 + n].decode()


def _chunk_records(content: bytes) -> bytes:
    """Return the (decompressed) records of a Chunk record's content."""
    (n,) = struct.unpack_from('<I', content, 28)
    compression = content[32:32 + n].decode()
    (size,) = struct.unpack_from('<Q', content, 32 + n)
    data = content[40 + n:40 + n + size]
    if compression == 'zstd':
        # lazy: optional dependency (zstandard)
        import zstandard
        return zstandard.ZstdDecompressor().decompress(
            data, max_output_size=struct.unpack_from('<Q', content, 16)[0])
    if compression == 'lz4':
        # lazy: optional dependency (lz4)
        import lz4.frame
        return lz4.frame.decompress(data)
    return data


def _scan(data: bytes, start: int, end: int, topics: dict, counts: dict):
    """Count messages per channel in the complete records of ``data[start:end]``."""
    pos = start
    while pos + _RECORD.size <= end:
        opcode, length = _RECORD.unpack_from(data, pos)
        body = pos + _RECORD.size
        if opcode in (_OP_DATA_END, _OP_FOOTER) or body + length > end:
            return
        if opcode == _OP_CHANNEL:
            cid, topic = _channel_topic(data[body:body + length])
            topics[cid] = topic
        elif opcode == _OP_MESSAGE:
            (cid,) = struct.unpack_from('<H', data, body)
            counts[cid] = counts.get(cid, 0) + 1
        elif opcode == _OP_CHUNK:
            records = _chunk_records(data[body:body + length])
            _scan(records, 0, len(records), topics, counts)
        pos = body + length


def committed_counts(bag) -> dict:
    """Return ``{topic: messages}`` already committed to a bag, even one still being written.

    MCAP: the complete records of the file (a chunk still being written does not
    count); sqlite3: the committed rows (read-only).  A bag with no data file
    yet, or a database that is busy, counts as empty.
    """
    bag = Path(bag)
    try:
        storage = storage_of(bag)
    except OSError:
        return {}
    path = data_file(bag)
    if storage == 'sqlite3':
        return _sqlite_counts(path)
    data = path.read_bytes()
    if data[:len(MAGIC)] != MAGIC:
        return {}
    topics: dict[int, str] = {}
    counts: dict[int, int] = {}
    _scan(data, len(MAGIC), len(data), topics, counts)
    return {topics.get(cid, str(cid)): n for cid, n in counts.items()}


def _sqlite_counts(path: Path) -> dict:

    try:
        conn = sqlite3.connect(f'file:{path}?mode=ro', uri=True, timeout=1.0)
        try:
            rows = conn.execute('SELECT topics.name, count(*) FROM messages JOIN topics '
                                'ON topics.id = messages.topic_id GROUP BY topics.name')
            return dict(rows.fetchall())
        finally:
            conn.close()
    except sqlite3.Error:
        return {}
