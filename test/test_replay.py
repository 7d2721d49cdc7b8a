"""Replay -> record round trip gives the same messages (issue 6, "Replay and review")."""

from pathlib import Path
import signal
import subprocess
import time

from rths_system_tests import REPO, graph_env, rths


def recorder_executable() -> str:
    from ament_index_python.packages import get_package_prefix
    return str(Path(get_package_prefix('rths_bringup')) / 'lib' / 'rths_bringup' / 'recorder')


def test_replay_then_record_gives_the_same_messages(tmp_path):
    from rths_common import bagio

    original = tmp_path / 'original'
    rths('launch', '--config', REPO / 'config', '--duration', 0.5, '--bag', original,
         timeout=240)
    copy = tmp_path / 'copy'
    recorder = subprocess.Popen(
        [recorder_executable(), '--ros-args', '-p', f'bag:={copy}', '-p', 'mode:=lockstep',
         '-p', 'fs_hz:=1024.0'], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        env=graph_env())
    try:
        out = rths('replay', original, '--rate-scale', 5, '--wait-for-subscribers', 1,
                   timeout=120).stdout
        assert 'replaying' in out
        time.sleep(0.5)
    finally:
        recorder.send_signal(signal.SIGINT)
        recorder.communicate(timeout=30)

    def by_topic(bag):
        out = {}
        reader = bagio.open_reader(bag)
        try:
            for conn, _, raw in reader.messages():
                out.setdefault(conn.topic, []).append(bytes(raw))
        finally:
            reader.close()
        return out

    a, b = by_topic(original), by_topic(copy)
    assert set(a) == set(b)
    for topic in a:
        assert len(a[topic]) == len(b[topic]), topic
        if topic == '/rths/status':  # three publishers interleave: compare as multisets
            assert sorted(a[topic]) == sorted(b[topic])
        else:
            assert a[topic] == b[topic], topic
