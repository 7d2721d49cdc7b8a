"""MCAP, the default storage of rths bags, and sqlite3, still written and read.

A bag written by rths must be readable by tools that are not rths: the ``mcap``
library (Foxglove's reference reader) and ``rosbags``.  A recording cut
anywhere (a killed recorder) must come back with every committed chunk.
"""

import shutil

import numpy as np
import pytest
from test_bagio import _measurement
import yaml

from rths_common import bagio, bagstore, topics


def _command(step):
    store = bagio.typestore()
    header = store.types['std_msgs/msg/Header']
    stamp = store.types['builtin_interfaces/msg/Time']
    return store.types['rths_msgs/msg/Command'](
        header=header(stamp=stamp(sec=0, nanosec=0), frame_id=''), step=step,
        command=np.array([0.001 * step]))


def _write(bag, n=200, storage='mcap', commit_every=50):
    """Write a bag of n measurements and n commands, committed every ``commit_every`` steps."""
    with bagio.BagWriter(bag, run_info={'fs_hz': 1024.0, 'kind': 'identification'},
                         storage=storage, commit_period_s=3600.0) as w:
        for k in range(n):
            w.write_msg(topics.COMMAND, 1000 + 2 * k, _command(k))
            w.write_msg(topics.MEASUREMENT, 1001 + 2 * k, _measurement(k))
            if (k + 1) % commit_every == 0:
                w.commit()
    return bag


def _meta(bag):
    return yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']


def test_default_bag_is_mcap_and_read_by_the_mcap_library_and_rosbags(tmp_path):
    from mcap.reader import make_reader
    from rosbags.rosbag2 import Reader

    bag = _write(tmp_path / 'bag', n=200)
    assert _meta(bag)['storage_identifier'] == 'mcap'
    [path] = bag.glob('*.mcap')
    with path.open('rb') as handle:                     # the mcap library, no rosbags
        reader = make_reader(handle)
        summary = reader.get_summary()
        schemas = {s.name: s for s in summary.schemas.values()}
        channels = {c.topic: c for c in summary.channels.values()}
        counts = {channels_id: n for channels_id, n
                  in summary.statistics.channel_message_counts.items()}
        seen = {}
        for _, channel, message in reader.iter_messages():
            seen[channel.topic] = seen.get(channel.topic, 0) + 1
            assert message.data[:4] == b'\x00\x01\x00\x00'   # CDR little-endian header
    for topic, msgtype in topics.LOOP_TOPICS.items():
        assert channels[topic].schema_id == schemas[msgtype].id
        assert channels[topic].message_encoding == 'cdr'
        assert schemas[msgtype].encoding == 'ros2msg' and schemas[msgtype].data
    assert seen == {topics.COMMAND: 200, topics.MEASUREMENT: 200}
    assert counts[channels[topics.MEASUREMENT].id] == 200
    with Reader(bag) as reader:                         # rosbags
        assert {c.topic: c.msgcount for c in reader.connections if c.msgcount} == seen
    steps = [m.step for _, m in bagio.read_topic(bag, topics.MEASUREMENT)]
    assert steps == list(range(200))


def test_sqlite3_storage_is_kept(tmp_path):
    bag = _write(tmp_path / 'bag', n=20, storage='sqlite3')
    assert _meta(bag)['storage_identifier'] == 'sqlite3' and list(bag.glob('*.db3'))
    info = bagio.info(bag)
    assert info['storage'] == 'sqlite3' and info['topics'][topics.COMMAND]['count'] == 20
    assert bagio.step_arrays(bag, topics.MEASUREMENT, ('force',))['force'][-1, 0] == 38.0
    with pytest.raises(ValueError, match='storage'):
        bagio.BagWriter(tmp_path / 'other', storage='rosbag1')


def test_a_data_file_path_is_read_as_its_bag(tmp_path):
    bag = _write(tmp_path / 'bag', n=10)
    [path] = bag.glob('*.mcap')
    assert bagio.info(path)['message_count'] == 20
    assert bagio.sampling_rate(path) == 1024.0


@pytest.mark.parametrize('cut', ['chunk', 'mid-chunk', 'footer'])
def test_mcap_cut_anywhere_keeps_every_committed_chunk(tmp_path, cut):
    """A file cut at a chunk end, inside the next chunk or in the summary is closed and read."""
    from mcap.reader import make_reader

    whole = _write(tmp_path / 'whole', n=200, commit_every=50)    # 4 chunks of 100 messages
    [path] = whole.glob('*.mcap')
    data = path.read_bytes()
    chunk_ends = _chunk_ends(data)
    assert len(chunk_ends) == 4
    end = {'chunk': chunk_ends[1], 'mid-chunk': chunk_ends[2] - 100,
           'footer': len(data) - 10}[cut]
    expected = {'chunk': 200, 'mid-chunk': 200, 'footer': 400}[cut]
    bag = tmp_path / 'cut'
    bag.mkdir()
    (bag / path.name).write_bytes(data[:end])
    shutil.copy(whole / bagio.RUN_INFO_FILE, bag)
    info = bagio.info(bag)                               # reindexes, repairing the file
    assert info['message_count'] == expected
    assert _meta(bag)['storage_identifier'] == 'mcap'
    assert bagio.sampling_rate(bag) == 1024.0
    with (bag / path.name).open('rb') as handle:
        assert sum(1 for _ in make_reader(handle).iter_messages()) == expected
    assert not bagstore.repair_mcap(bag / path.name)    # now complete: left alone


def _chunk_ends(data: bytes) -> list:
    """Offsets just past each chunk record's trailing message indexes (top level)."""
    import struct

    pos, ends = 8, []
    while pos + 9 <= len(data):
        opcode, length = struct.unpack_from('<BQ', data, pos)
        if opcode == 0x0F:
            break
        pos += 9 + length
        if opcode == 0x06:
            ends.append(pos)
    return ends


def test_repair_refuses_a_file_that_is_not_mcap(tmp_path):
    path = tmp_path / 'x.mcap'
    path.write_bytes(b'not an mcap file at all, not at all')
    with pytest.raises(OSError, match='not an MCAP file'):
        bagstore.repair_mcap(path)


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_committed_counts_of_a_bag_still_being_written(tmp_path, storage):
    bag = tmp_path / 'bag'
    assert bagstore.committed_counts(bag) == {}
    w = bagio.BagWriter(bag, storage=storage, commit_period_s=3600.0)
    for k in range(100):
        w.write_msg(topics.MEASUREMENT, 10 + k, _measurement(k))
    w.commit()
    for k in range(100, 150):                       # written, not committed
        w.write_msg(topics.MEASUREMENT, 10 + k, _measurement(k))
    assert bagstore.committed_counts(bag) == {topics.MEASUREMENT: 100}
    w.close()
    assert bagstore.committed_counts(bag) == {topics.MEASUREMENT: 150}
