"""``rths bench discrepancy-rths``: its cases, their configs and the targets it reports."""

import pytest

from rths_bench import bench_discrepancy_rths as b


def test_every_hidden_effect_of_the_simulated_lab_is_a_case_at_two_sizes():
    from rths_actuator_bridge.simulated import HIDDEN_EFFECTS

    keys = [c[1] for c in b.CASES]
    for key, (scenario, effect) in HIDDEN_EFFECTS.items():
        cases = [c for c in b.CASES if c[1] == key]
        assert {c[3] for c in cases} == {scenario}
        if effect is None:      # outside the library: must end 'unexplained'
            assert [c[4] for c in cases] == ['unexplained']
        else:
            assert len(cases) == 2 and {c[4] for c in cases} == {effect}
    assert keys.count(None) == 2    # the nominal controls


def test_a_case_config_hides_its_key_in_the_bridge_only(tmp_path):
    from rths_bringup.commands import default_config_dir
    from rths_common import runinfo

    cfg = b.case_config(default_config_dir(), tmp_path / 'c', 'specimen_backlash_m', 1e-3)
    bridge = runinfo.load_params(cfg / 'bridge.yaml', 'bridge')
    assert bridge['specimen_backlash_m'] == 1e-3 and bridge['specimen'] == 'valve4'
    assert (cfg / 'numerical.yaml').read_text() == (default_config_dir()
                                                    / 'numerical.yaml').read_text()


def _row(hidden, named, err=None, after=0.1):
    return {'hidden': hidden, 'named': named, 'named_correctly': named == hidden,
            'parameter_error_pct': err, 'rths_vs_reference_after_pct': after}


def test_summary_counts_the_targets():
    rows = [_row('none', 'none', after=0.4), _row('none', 'none', after=0.3),
            _row('coulomb_friction', 'coulomb_friction', 3.0, 0.2),
            _row('mass_error', 'mass_error', -20.0, 0.7),      # within 2x the control's 0.4
            _row('backlash', 'none', None, 5.0),
            _row('unexplained', 'unexplained')]
    s = b.summarise(rows)
    assert s['hidden_cases'] == 3
    assert s['named_pct'] == pytest.approx(200 / 3)
    assert s['parameters_within_15_pct'] == [1, 3]
    assert s['rerun_within_target'] == [2, 3]
    assert s['names_in_controls'] == 0
    assert s['outside_library_unexplained'] == [1, 1]


def test_held_out_specimens_are_a_swapped_valve_and_the_mr_damper(tmp_path):
    from rths_bringup.commands import default_config_dir
    from rths_common import runinfo

    assert [(c[0], c[1]) for c in b.SPECIMEN_CASES] == [('swapped_valve', 'valve2'),
                                                        ('mr_damper', 'mr')]
    cfg = b.case_config(default_config_dir(), tmp_path / 'c', None, 0.0, specimen='valve2')
    bridge = runinfo.load_params(cfg / 'bridge.yaml', 'bridge')
    assert bridge['specimen'] == 'valve2' and 'dtm' not in bridge


def test_specimen_summary_needs_both_valve_parameters_within_15_pct():
    rows = [{'case': 'swapped_valve', 'named_correctly': True,
             'parameter_errors_pct': {'dc': 9.7, 'dk': -21.5}},    # issue 35's biased fit
            {'case': 'mr_damper', 'named_correctly': False}]
    s = b.summarise_specimens(rows)
    assert s == {'swapped_valve_named': True, 'swapped_valve_parameters_within_15_pct': False,
                 'mr_damper_analysed': False}
    rows[0]['parameter_errors_pct']['dk'] = 3.0
    assert b.summarise_specimens(rows)['swapped_valve_parameters_within_15_pct']


def test_an_effect_the_compensator_cannot_use_has_no_rerun_and_says_why():
    # a linear compensator folds the linear loads and the delay, and applies the Coulomb and
    # cubic loads as its feed-forward; the play, the rate limit and a sensor offset are
    # refused by rths design (rths_compensator.plant_effects), so their case has no re-run
    assert b._refused_by_design('stiffness_error') is None
    assert b._refused_by_design('time_delay+mass_error') is None
    assert b._refused_by_design('cubic_stiffness') is None
    assert b._refused_by_design('stiffness_error+coulomb_friction') is None
    why = b._refused_by_design('backlash')
    assert 'backlash' in why and 'reading' in why
    assert 'backlash' in b._refused_by_design('coulomb_friction+backlash')
    rows = [_row('none', 'none', after=0.1),
            dict(_row('backlash', 'backlash', 1.0, 3.5), rerun='none: ' + why)]
    s = b.summarise(rows)
    assert s['rerun_refused'] == 1 and s['rerun_within_target'] == [0, 1]
