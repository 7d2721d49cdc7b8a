"""Damaged bags are read as far as they can be, or refused in one line; never a traceback.

Three damages a lab meets: the MCAP file cut in half under the metadata.yaml that was
kept (a disk full, a copy interrupted), bytes overwritten inside the data, and a
truncated metadata.yaml.  ``rths bag info`` reported the full counts of the
metadata for a file whose data could not be read.
"""

import os
import random

import pytest

from rths_common import bagio, cdr, topics

N = 4000


@pytest.fixture
def bag(tmp_path):
    path = tmp_path / 'bag'
    with bagio.BagWriter(path, topics.LOOP_TOPICS, commit_period_s=0.0) as writer:
        for k in range(N):
            t = 1_000_000_000 + k * 976_562
            writer.write(topics.MEASUREMENT, t, cdr.pack_step_arrays(t, k, [0.0], [0.0], [k]))
            writer.commit()
    return path


def _steps(bag):
    return [m.step for _, _, m in bagio.read_messages(bag, [topics.MEASUREMENT])]


def test_an_mcap_cut_in_half_under_its_metadata_reads_its_first_half(bag):
    mcap = next(bag.glob('*.mcap'))
    with open(mcap, 'r+b') as f:
        f.truncate(os.path.getsize(mcap) // 2)
    steps = _steps(bag)
    assert 0 < len(steps) < N and steps == list(range(len(steps)))
    info = bagio.info(bag)
    assert info['topics'][topics.MEASUREMENT]['count'] == len(steps) and not info['damaged']


def test_overwritten_bytes_are_a_one_line_error_and_info_counts_what_can_be_read(bag):
    mcap = next(bag.glob('*.mcap'))
    size = os.path.getsize(mcap)
    rng = random.Random(1)
    with open(mcap, 'r+b') as f:
        for _ in range(20):                    # 20 runs of 64 random bytes past the first 10 %
            f.seek(rng.randrange(size // 10, size - 100))
            f.write(rng.randbytes(64))
    with pytest.raises(bagio.BagDamaged, match=r'^\S+/bag: .*damaged .*\)[;:] '):
        _steps(bag)
    try:
        info = bagio.info(bag)
    except bagio.BagDamaged:
        return                                  # not even its index can be read: said so
    assert info['damaged'] and info['topics'][topics.MEASUREMENT]['count'] < N
    assert info['message_count'] == info['topics'][topics.MEASUREMENT]['count']


def test_a_truncated_metadata_yaml_is_rebuilt_and_the_old_one_kept(bag):
    meta = bag / 'metadata.yaml'
    text = meta.read_text()
    meta.write_text(text[:len(text) // 2])
    assert _steps(bag) == list(range(N))
    assert (bag / 'metadata.yaml.damaged').read_text() == text[:len(text) // 2]


@pytest.mark.parametrize('text', ['- a\n- b\n', '{rosbag2_bagfile_information: 3}\n', ': : :\n'])
def test_run_info_of_a_metadata_yaml_that_is_not_a_mapping_is_rebuilt(tmp_path, text):
    path = tmp_path / 'bag'
    with bagio.BagWriter(path, topics.LOOP_TOPICS, run_info={'fs_hz': 1024.0}) as writer:
        writer.write(topics.MEASUREMENT, 1, cdr.pack_step_arrays(1, 0, [0.0], [0.0], [0.0]))
    (path / 'metadata.yaml').write_text(text)
    assert float(bagio.run_info(path)['fs_hz']) == 1024.0
    assert (path / 'metadata.yaml.damaged').read_text() == text
