"""``rths bench monitor``: a small seeded configuration through the command, its JSON fields."""

import json

from rths_bringup.cli import main


def test_bench_monitor_detects_the_delay_step_without_false_alarm(tmp_path):
    out = tmp_path / 'monitor.json'
    code = main(['bench', 'monitor', '--out', str(out), '--duration', '8', '--faulty', '2',
                 '--draws', '1'])
    assert code == 0
    res = json.loads(out.read_text())
    assert list(res)[:6] == ['runs', 'detected', 'false_alarms', 'nominal_runs', 'detect_s_max',
                             'limits_tripped']
    assert res['runs'] == 2 and res['nominal_runs'] == 8        # 4 cases x (nominal + 1 draw)
    assert res['detected'] == 2 and res['false_alarms'] == 0 and res['limits_tripped'] == 0
    assert 0 < res['detect_s_max'] <= 0.5
    faulty = [r for r in res['details']['runs'] if r['change_s'] is not None]
    assert all(r['stop_s'] > r['change_s'] for r in faulty)
