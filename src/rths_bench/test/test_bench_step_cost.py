"""``rths bench adaptive --step-cost``: the JSON's fields, on the project's 1024 Hz run.

Timing itself is not asserted (a benchmark's figure, docs/bench/adaptive_step_cost): what
is checked is that every method ran the scenario it is timed in (the adaptive ones
adapting, none fallen back) and that the fields the issue names are there.
"""

import json

import pytest

from rths_bench.bench_step_cost import run_step_cost


def test_step_cost_writes_every_method_at_the_rate(tmp_path):
    out = run_step_cost(str(tmp_path), duration_s=1.5, rates=(1024,), log=lambda _m: None)
    saved = json.loads((tmp_path / 'summary.json').read_text())
    assert saved['rates'].keys() == out['rates'].keys() == {'1024'}
    block = saved['rates']['1024']
    assert block['design']['taps'] > 32            # config/compensator.yaml's long FIR
    methods = block['methods']
    assert set(methods) >= {'fir', 'rls_fir', 'ats', 'amb', 'pi_lead'}
    for name, row in methods.items():
        for key in ('step_us_p50', 'step_us_p99', 'core_step_us_p50', 'core_step_us_p99'):
            assert 0.0 < row[key] < 1e6, (name, key)
        assert row['step_us_p50'] <= row['step_us_p99']
        assert sum(row['states'].values()) == int(1.5 * 1024)
    for name in ('rls_fir', 'ats', 'amb'):
        states = methods[name]['states']
        assert states.get('adapting', 0) > 1024 and 'fallback' not in states, (name, states)
    assert len(saved['load_average_start']) == 3 and saved['floor_empty_call_us_p50'] > 0


def test_step_cost_refuses_a_rate_without_a_scenario(tmp_path):
    with pytest.raises(ValueError, match='2048 Hz has no scenario'):
        run_step_cost(str(tmp_path), rates=(2048,))
    with pytest.raises(ValueError, match='too short'):
        run_step_cost(str(tmp_path), duration_s=0.5)
