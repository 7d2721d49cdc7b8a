"""The node graph as separate processes: closed-loop progress, recording, crashes.

Issue 2 ("Tests that must exist"): launch the graph, run a few seconds and
check the loop made progress on every topic, in order, with no gaps (lock-step);
kill one node and check the launcher names it and the bag stays readable.
"""

import json
import os
import signal

import pytest

from rths_review.review import STEP_TOPICS
from rths_system_tests import (
    REPO,
    Drain,
    launch_background,
    rths,
    sigkill_mid_run,
    started_pids,
    wait_committed,
    wait_for,
    wait_steps,
)

CONFIG = REPO / 'config'
FS_HZ = 1024.0


def read_steps(bag):
    from rths_review.review import read_loop
    return read_loop(bag)


def test_lockstep_run_progresses_on_every_topic(tmp_path):
    bag = tmp_path / 'bag'
    duration = 2.0
    proc = rths('launch', '--config', CONFIG, '--duration', duration, '--bag', bag, timeout=240)
    assert 'run finished' in proc.stdout
    assert '\r' not in proc.stdout + proc.stderr        # a pipe: no carriage returns
    assert 'progress: step' not in proc.stdout          # the launcher's progress, on stderr
    # logs are streamed with node-name prefixes
    for name in ('numerical', 'compensator', 'bridge', 'recorder'):
        assert f'[{name}]' in proc.stdout, name
    n_steps = int(round(duration * FS_HZ))
    loop = read_steps(bag)
    from rths_review.review import step_check
    for topic, data in loop['steps'].items():
        check = step_check(data['step'])
        assert check['count'] == n_steps, (topic, check)
        assert check['first'] == 0 and check['last'] == n_steps - 1, (topic, check)
        assert check['gaps'] == 0 and check['duplicates'] == 0 and check['in_order'], topic
    # every node reported status for every step
    for node in ('numerical', 'compensator', 'bridge'):
        assert len(loop['status'][node]['step']) == n_steps, node
    # the review rebuilds from the bag alone (run parameters incl. node-level keys in the bag)
    rths('review', bag, '--out', tmp_path / 'review')
    summary = json.loads((tmp_path / 'review' / 'summary.json').read_text())
    assert summary['steps'] == n_steps and summary['deadline_misses'] == 0
    # issue 17: the MCAP bag's review is one offline HTML file, every plot embedded
    assert 'storage_identifier: mcap' in (bag / 'metadata.yaml').read_text()
    report = (tmp_path / 'review' / 'report.html').read_text()
    assert report.count('src="data:image/png;base64,') == 3
    assert 'http://' not in report and 'https://' not in report


def test_bag_info_reads_the_bag(tmp_path):
    bag = tmp_path / 'bag'
    rths('launch', '--config', CONFIG, '--duration', 0.5, '--bag', bag, timeout=240)
    out = rths('bag', 'info', bag).stdout
    assert '/rths/measurement' in out and 'rths_msgs/msg/Measurement' in out
    assert ' 512' in out  # 0.5 s at 1024 Hz


# (the loop nodes' SIGKILL: test_faults_graph, which checks the same and the safe state too)
@pytest.mark.parametrize('victim', ['recorder'])
def test_sigkill_of_a_node_fails_the_run_names_it_and_keeps_the_bag(tmp_path, victim):
    bag = tmp_path / 'bag'
    proc = launch_background(CONFIG, bag, '--duration', 600.0)
    try:
        out = sigkill_mid_run(proc, bag, victim, timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 1, out[-3000:]
    assert f'node {victim} died (killed by SIGKILL)' in out
    assert f'FAILED: node {victim}' in out
    # The bag is readable and holds the steps up to the crash, in order, without gaps.
    from rths_review.review import step_check
    loop = read_steps(bag)
    for topic, data in loop['steps'].items():
        check = step_check(data['step'])
        assert check['count'] > 100, (topic, check)
        assert check['first'] == 0 and check['gaps'] == 0 and check['in_order'], (topic, check)
    if victim == 'recorder':
        assert (bag / 'metadata.yaml').exists()


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM])
def test_ctrl_c_or_sigterm_stops_every_node_and_closes_the_bag(tmp_path, sig):
    """Issue 2: the launcher shuts the whole graph down cleanly on Ctrl-C/SIGTERM."""
    bag = tmp_path / 'bag'
    proc = launch_background(CONFIG, bag, '--duration', 600.0)
    try:
        head = wait_for(proc, 'graph connected')
        drain = Drain(proc, head)
        wait_steps(bag, 1024, drain=drain)
        committed = wait_committed(bag, STEP_TOPICS, 100, drain=drain)   # (the recorder lags)
        pids = started_pids(head)
        proc.send_signal(sig)
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    out = drain.text()
    assert proc.returncode == 128 + sig, out[-3000:]       # 130 / 143, as a shell reports it
    assert f'{signal.Signals(sig).name} received: stopping all nodes' in out
    assert set(pids) == {'numerical', 'compensator', 'bridge', 'recorder'}
    for name, pid in pids.items():                          # no node left behind
        assert not os.path.exists(f'/proc/{pid}') or 'zombie' in open(
            f'/proc/{pid}/status').read().lower(), name
    assert (bag / 'metadata.yaml').exists()                 # closed by the recorder itself
    from rths_review.review import step_check
    loop = read_steps(bag)
    for topic, data in loop['steps'].items():
        check = step_check(data['step'])
        assert check['count'] >= committed[topic] and check['first'] == 0, (topic, check)
        assert check['gaps'] == 0 and check['in_order'], (topic, check)
