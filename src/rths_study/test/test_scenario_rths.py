"""The ``rths-offline`` scenario: rths run's RTHS and review, offline, per run of a study.

A short Kobe run (3 s of the seed's record x 0.135, 2-story building, valve #4 DTM x 5,
simulated 3-pole actuator) with the config's designed FIR, and the same run with identity
taps: compensation takes the actuator's delay (seed table 5: ~15-21 ms before) to about
zero and brings the RTHS close to the whole-numerical reference.
"""

import math

import pytest

from rths_study.spec import check_spec
from rths_study.worker import evaluate_chunk


def _spec(**over):
    raw = {'study': 't', 'scenario': {'kind': 'rths-offline', 'duration_s': 3.0},
           'parameters': {'list': [{'force_scale': 5.0}, {'force_scale': 1.0}]},
           'records': ['kobe']}
    raw['scenario'].update(over)
    return check_spec(raw)


def _rows(spec):
    return evaluate_chunk(spec.kind, spec.settings, [r.as_dict() for r in spec.runs()],
                          spec.metrics)


def test_compensation_removes_the_delay_and_follows_the_reference():
    fir = _rows(_spec())
    none = _rows(_spec(compensator='none'))
    for row in fir + none:
        assert row['status'] == 'ok' and not row['safety_stop'], row
        assert row['steps'] == 3072
        assert 10.0 < row['delay_ms_before'] < 25.0          # the plant's own delay
    for comp, plain in zip(fir, none, strict=True):
        assert abs(comp['delay_ms_after']) < 2.0
        assert plain['delay_ms_after'] == pytest.approx(plain['delay_ms_before'], abs=0.5)
        assert comp['tracking_rel_rms_pct_after'] < 0.5 * plain['tracking_rel_rms_pct_after']
        assert comp['rths_vs_reference_rel_rms_pct'] < plain['rths_vs_reference_rel_rms_pct']
        assert math.isfinite(comp['reduction_rms_pct'])
    # the uncompensated delay's error grows with the specimen force fed back (5 DTMs vs 1)
    assert none[0]['rths_vs_reference_rel_rms_pct'] > 2 * none[1]['rths_vs_reference_rel_rms_pct']


def test_refusals_name_the_field(tmp_path):
    with pytest.raises(ValueError, match='scenario.compensator'):
        _spec(compensator=str(tmp_path / 'missing.yaml'))
    with pytest.raises(ValueError, match='needs a designed FIR'):
        check_spec({'study': 't', 'scenario': {'kind': 'rths-offline', 'compensator': 'none'},
                    'controllers': ['fir', 'amb']})
    with pytest.raises(ValueError, match=r'parameters.grid.specimen\[0\]'):
        check_spec({'study': 't', 'scenario': {'kind': 'rths-offline'},
                    'parameters': {'grid': {'specimen': ['valve9']}}})
    with pytest.raises(ValueError, match=r'records\[0\]'):
        check_spec({'study': 't', 'scenario': {'kind': 'rths-offline'}, 'records': ['nope']})
