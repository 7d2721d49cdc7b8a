"""rths bench adaptive on a tiny configuration: the summary layout and the scenarios' size."""

import json

from rths_bringup.bench_adaptive import SCENARIOS, recovery_s, run_bench

FIELDS = {'rms_pct_before_change', 'rms_pct_after_change', 'delay_ms_after_change',
          'recovery_s', 'stable', 'step_us_p50'}


def test_summary_layout_and_scenario_size(tmp_path):
    assert SCENARIOS == ('unchanged', 'stiffness_drop', 'plant_drift')
    run_bench(str(tmp_path), duration_s=8.0, taps=16, plots=False,
              scenarios=('stiffness_drop',))
    summary = json.loads((tmp_path / 'summary.json').read_text())
    assert set(summary) == {'scenarios'}
    assert set(summary['scenarios']) == {'stiffness_drop'}
    for block in summary['scenarios'].values():
        assert set(block) == {'fir', 'rls_fir', 'ats', 'amb'}
        for m in block.values():
            assert set(m) == FIELDS
            assert m['stable'] is True
    fir = summary['scenarios']['stiffness_drop']['fir']
    # the issue: the stiffness drop is sized so that the fixed FIR's error at least doubles
    assert fir['rms_pct_after_change'] >= 2 * fir['rms_pct_before_change']
    config = json.loads((tmp_path / 'config.json').read_text())
    assert config['change_s'] == 4.0 and 'stiffness_drop' in config['scenarios']


def test_recovery_time_definition():
    assert recovery_s([1.0, 1.0], 2.0, 2.0) == 0.0
    assert recovery_s([1.0, 3.0, 2.5, 1.5, 3.0], 2.0, 2.0) == 8.0
    assert recovery_s([3.0, 3.0], 2.0, 2.0) is None
