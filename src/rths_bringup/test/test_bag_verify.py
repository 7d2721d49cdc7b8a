"""The bag as evidence: ``rths bag verify`` finds damage and gaps, ``rths bag repair`` a killed run.

Bags are written here as the recorder writes them (:class:`BagWriter`, one
measurement, one bridge status, one interface displacement and one command per
tick at 1024 Hz), then damaged the way a lab meets it: bytes changed on disk,
ticks the recorder lost, a writer killed with SIGKILL mid-run.
"""

import json
import os
import signal
import subprocess
import sys
import textwrap

import pytest

from rths_bringup.cli import main as rths
from rths_common import bagio, bagstore, cdr, provenance, topics
from rths_review.evidence import repair, verify

FS = 1024.0
N = 2048            # 2 s of ticks
STEP_NS = int(1e9 / FS)


def write_run(path, storage='mcap', skip=(), skip_commands=(), n=N, run_info=None):
    """Write a run bag of ``n`` ticks, without the measurement/status of ``skip``."""
    info = {'fs_hz': repr(FS), 'kind': 'rths', 'numerical.duration_s': repr(n / FS)}
    info.update(run_info or {})
    with bagio.BagWriter(path, topics.LOOP_TOPICS, run_info=info, storage=storage,
                         commit_period_s=0.05) as writer:
        for k in range(n):
            t = 1_000_000_000 + k * STEP_NS
            u = [0.001 * (k % 100)]
            writer.write(topics.INTERFACE_DISPLACEMENT, t, cdr.pack_step_arrays(t, k, u))
            if k not in skip_commands:
                writer.write(topics.COMMAND, t, cdr.pack_step_arrays(t, k, u))
            if k in skip:
                continue
            writer.write(topics.MEASUREMENT, t, cdr.pack_step_arrays(t, k, u, u, [1.0]))
            writer.write(topics.STATUS, t, cdr.pack_status(t, 'bridge', k))
            if k % 256 == 0:
                writer.commit()
    return path


def test_a_whole_run_bag_verifies_with_every_chunk_checked(tmp_path):
    bag = write_run(tmp_path / 'bag', run_info=provenance.collect())
    report = verify(bag)
    assert report['problems'] == []
    i = report['integrity']
    assert i['chunks'] > 5 and i['chunks_checked'] == i['chunks'] and not i['bad_chunks']
    comp = report['completeness']
    assert comp['bridge_ticks'] == N == comp['planned_steps']
    assert comp['topics'][topics.MEASUREMENT]['count'] == N
    assert report['provenance']['rths_version'] and report['provenance']['host']
    assert rths(['bag', 'verify', str(bag)]) == 0


def test_a_changed_byte_fails_its_chunk_crc(tmp_path, capsys):
    bag = write_run(tmp_path / 'bag')
    mcap = bagstore.data_file(bag)
    before = bagstore.check_integrity(bag)
    with open(mcap, 'r+b') as f:        # one float of a message in the middle of the file
        f.seek(os.path.getsize(mcap) // 2)
        byte = f.read(1)
        f.seek(-1, os.SEEK_CUR)
        f.write(bytes([byte[0] ^ 0x01]))
    report = verify(bag)
    assert len(report['integrity']['bad_chunks']) == 1 and before['ok']
    assert any('CRC-32' in p for p in report['problems'])
    assert rths(['bag', 'verify', str(bag)]) == 1
    assert 'BAG NOT OK' in capsys.readouterr().out


def test_lost_ticks_make_the_bag_incomplete(tmp_path):
    bag = write_run(tmp_path / 'bag', skip={500, 501, 502})
    report = verify(bag)
    assert report['integrity']['ok']
    assert any('lacks 3 of' in p for p in report['problems']), report['problems']


def test_a_short_command_gap_is_filled_and_a_long_one_fails(tmp_path):
    short = verify(write_run(tmp_path / 'short', skip_commands={700}))
    assert short['problems'] == []
    assert short['completeness']['topics'][topics.COMMAND]['filled'] == 1
    gap = set(range(700, 700 + int(0.2 * FS)))       # 0.2 s: longer than the review fills
    long = verify(write_run(tmp_path / 'long', skip_commands=gap))
    assert any(topics.COMMAND in p and 'missing' in p for p in long['problems'])


def test_sqlite3_is_checked_by_its_integrity_check(tmp_path):
    report = verify(write_run(tmp_path / 'bag', storage='sqlite3'))
    assert report['integrity']['result'] == 'ok' and report['problems'] == []


def test_provenance_carries_the_config_files_and_the_plant_they_name(tmp_path):
    root = os.environ.get('RTHS_ROOT')
    if not root:
        pytest.skip('RTHS_ROOT not set (source env.sh)')
    info = provenance.collect(os.path.join(root, 'config'))
    prov = provenance.of_run_info(info)
    assert {'bridge.yaml', 'compensator.yaml', 'numerical.yaml', 'plant.yaml'} <= set(
        prov['files'])
    text = prov['files']['compensator.yaml']['text']
    assert 'taps:' in text          # the taps the run used (runinfo.SKIP leaves them out)
    bag = write_run(tmp_path / 'bag', run_info=info)
    kept = provenance.of_run_info(bagio.run_info(bag))
    assert kept['files']['plant.yaml'] == prov['files']['plant.yaml']


CHILD = textwrap.dedent('''
    import json, os, signal, sys, time
    from rths_common import bagio, cdr, topics
    bag, side = sys.argv[1], sys.argv[2]
    writer = bagio.BagWriter(bag, topics.LOOP_TOPICS, storage=sys.argv[3],
                             run_info={'fs_hz': '1024.0', 'numerical.duration_s': '10.0'},
                             commit_period_s=0.05)
    stamps = []
    start = time.monotonic()
    k = 0
    while k < 400 or time.monotonic() - start < 1.0:   # at least 400 ticks however loaded
        t = time.monotonic_ns()
        for topic in (topics.INTERFACE_DISPLACEMENT, topics.COMMAND):
            writer.write(topic, t, cdr.pack_step_arrays(t, k, [0.0]))
        writer.write(topics.MEASUREMENT, t, cdr.pack_step_arrays(t, k, [0.0], [0.0], [0.0]))
        writer.write(topics.STATUS, t, cdr.pack_status(t, 'bridge', k))
        stamps.append(t)
        k += 1
        time.sleep(0.001)
    with open(side, 'w') as f:
        json.dump(stamps, f)
    os.kill(os.getpid(), signal.SIGKILL)
''')


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_a_killed_recording_is_refused_then_repaired_up_to_100_ms_before_the_kill(
        tmp_path, storage):
    bag, side = tmp_path / 'bag', tmp_path / 'produced.json'
    proc = subprocess.run([sys.executable, '-c', CHILD, str(bag), str(side), storage],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    data = bagstore.data_file(bag)
    size = data.stat().st_size
    cut = verify(bag)
    assert any("rths bag repair" in p for p in cut['problems'])
    assert data.stat().st_size == size and not (bag / 'metadata.yaml').exists()  # untouched
    assert rths(['bag', 'repair', str(bag)]) == 0
    produced = json.loads(side.read_text())
    must = [k for k, t in enumerate(produced) if t <= produced[-1] - 0.1e9]
    kept = [m.step for _, _, m in bagio.read_messages(bag, [topics.MEASUREMENT])]
    assert len(must) > 100 and kept == list(range(len(kept))) and len(kept) >= len(must)
    after = verify(bag)
    assert after['integrity']['ok'] if storage == 'sqlite3' else (
        after['integrity']['closed'] and not after['integrity']['bad_chunks'])
    assert after['completeness']['bridge_ticks'] == len(kept)
    assert after['completeness']['recovered_after_crash']
    assert any('recovered after a crash' in p for p in after['problems'])   # exit 1: cut short
    assert repair(bag)['repaired'] is False          # a second repair changes nothing
