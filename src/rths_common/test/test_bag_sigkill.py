"""A SIGKILL mid-recording loses at most the last 0.1 s: the repaired bag holds every sample before.

A child process writes one measurement per millisecond with :class:`BagWriter`'s
default commit period, notes the time of every sample it produced, and kills
itself with SIGKILL mid-run. The bag, reindexed on read, must hold every sample
produced up to 100 ms before the kill, in order and without a gap.
"""

import json
import os
import signal
import subprocess
import sys
import textwrap

import pytest

from rths_common import bagio, topics

CHILD = textwrap.dedent('''
    import json, os, signal, sys, time
    from rths_common import bagio, cdr, topics
    bag, side = sys.argv[1], sys.argv[2]
    writer = bagio.BagWriter(bag, topics.LOOP_TOPICS, storage=sys.argv[3])
    stamps = []
    start = time.monotonic()
    k = 0
    while time.monotonic() - start < 0.8:
        t = time.monotonic_ns()
        writer.write(topics.MEASUREMENT, t, cdr.pack_step_arrays(t, k, [0.0], [0.0], [0.0]))
        stamps.append(t)
        k += 1
        time.sleep(0.001)
    with open(side, 'w') as f:
        json.dump(stamps, f)
    os.kill(os.getpid(), signal.SIGKILL)
''')

LOSS_S = 0.1


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_sigkill_mid_run_loses_at_most_the_last_100_ms(tmp_path, storage):
    bag, side = tmp_path / 'bag', tmp_path / 'produced.json'
    proc = subprocess.run([sys.executable, '-c', CHILD, str(bag), str(side), storage],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    assert not (bag / 'metadata.yaml').exists()          # killed: nothing was closed
    produced = json.loads(side.read_text())
    kept = [m.step for _, _, m in bagio.read_messages(bag, [topics.MEASUREMENT])]
    assert kept == list(range(len(kept)))                 # in order, no gap
    kill_ns = produced[-1]
    must = [k for k, t in enumerate(produced) if t <= kill_ns - LOSS_S * 1e9]
    assert len(must) > 100
    assert len(kept) >= len(must), (
        f'{len(must) - len(kept)} samples older than {LOSS_S} s before the kill are missing')
    assert os.path.getsize(bagio.bag_dir(bag) / 'metadata.yaml') > 0   # rebuilt by reindex
