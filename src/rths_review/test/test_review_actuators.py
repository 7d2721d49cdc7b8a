"""The review of a run with two actuators on one specimen: Table 5 per actuator and per DOF.

The bag is written here step by step, as the maRTHS graph records it (numerical model
``marths``, bridge ``simulated_rig`` with config/rig_two_actuators.yaml, one entry per
actuator in every message): the targets come from a known interface motion (x, theta)
through the rig's coupler; each actuator's command leads its target by 2 samples (a
compensator) and its measured stroke lags the command by its own delay (10 and 25
samples), so every delay the review reports is known.  No ROS graph runs.
"""

import json
from pathlib import Path

import numpy as np
import pytest

from rths_common import cdr, runinfo, topics
from rths_common.bagio import BagWriter
from rths_common.rig import load_rig

FS = 1024.0
CONFIG = Path(__file__).resolve().parents[3] / 'config'
RIG = CONFIG / 'rig_two_actuators.yaml'
LAG = (10, 25)        # samples each actuator's measured stroke lags its command
LEAD = 2              # samples each command leads its target
T0_NS = 1_800_000_000_000_000_000


def _sections(record, rig_file):
    numerical = {'model': 'marths', 'fs_hz': FS, 'record': str(record), 'scale': 1.0,
                 'duration_s': 0.0, 'record_resample': False, 'record_remove_mean': False,
                 'record_baseline': False}
    return {'numerical': numerical,
            'compensator': {'scheme': 'ls', 'fs_hz': FS},
            'bridge': {'backend': 'simulated_rig', 'rig_file': str(rig_file), 'fs_hz': FS}}


def _shift(x, lag):
    """``x`` delayed by ``lag`` samples (advanced when negative), held at the ends."""
    if lag >= 0:
        return np.r_[np.full(lag, x[0]), x[:x.size - lag]]
    return np.r_[x[-lag:], np.full(-lag, x[-1])]


def write_bag(tmp_path, rig_file=RIG):
    """Return ``(bag, truth)``: a two-actuator lock-step bag and the motion written into it."""
    from rths_numerical.substructure import make_substructure

    t = np.arange(0, 4.0, 1.0 / FS)
    record = tmp_path / 'pulse.txt'
    np.savetxt(record, np.column_stack([t, 0.3 * np.sin(2 * np.pi * 2 * t)]), delimiter=',',
               header='time [s],accel [m/s^2]', comments='')
    sections = _sections(record, rig_file)
    n = make_substructure(sections['numerical']).n_steps
    k = np.arange(n) / FS
    env = np.sin(np.pi * k / k[-1]) ** 2
    x = 2e-3 * env * np.sin(2 * np.pi * 2.1 * k)
    theta = 5e-3 * env * np.sin(2 * np.pi * 3.3 * k + 0.4)
    rig = load_rig(RIG)
    target = rig.to_strokes(x, theta).T                       # steps x 2 [m]
    command = np.column_stack([_shift(target[:, i], -LEAD) for i in range(2)])
    measured = np.column_stack([_shift(command[:, i], LAG[i]) for i in range(2)])
    force = 1e4 * measured
    info = runinfo.flatten('rths', FS, 'lockstep', sections)
    period = int(1e9 / FS)
    with BagWriter(tmp_path / 'bag', topics.LOOP_TOPICS, run_info=info) as bag:
        for step in range(n):
            stamp = T0_NS + step * period
            bag.write(topics.INTERFACE_DISPLACEMENT, stamp,
                      cdr.pack_step_arrays(stamp, step, target[step]))
            bag.write(topics.COMMAND, stamp, cdr.pack_step_arrays(stamp, step, command[step]))
            bag.write(topics.MEASUREMENT, stamp, cdr.pack_step_arrays(
                stamp, step, command[step], measured[step], force[step]))
            bag.write(topics.STATUS, stamp, cdr.pack_status(stamp + 50_000, 'bridge', step))
    return tmp_path / 'bag', {'n': n, 'x': x, 'theta': theta}


@pytest.fixture(scope='module')
def reviewed(tmp_path_factory):
    from rths_review.review import review_rths
    tmp = tmp_path_factory.mktemp('two')
    bag, truth = write_bag(tmp)
    return review_rths(bag, tmp / 'review'), truth, tmp / 'review'


def test_each_actuator_gets_its_own_table_5(reviewed):
    s, truth, out = reviewed
    assert s['kind'] == 'actuators' and s['n_actuators'] == 2 and s['steps'] == truth['n']
    assert [a['name'] for a in s['actuators']] == ['lower', 'upper']   # the rig file's names
    for a, lag in zip(s['actuators'], LAG, strict=True):
        # before: command -> measured, the actuator's own lag; after: target -> measured
        assert a['delay_ms_before'] == pytest.approx(1e3 * lag / FS, abs=0.05)
        assert a['delay_ms_after'] == pytest.approx(1e3 * (lag - LEAD) / FS, abs=0.05)
        assert a['tracking_rel_rms_pct_after'] > 5.0
    # the later actuator tracks worse
    assert (s['actuators'][1]['tracking_rel_rms_pct_after']
            > 2 * s['actuators'][0]['tracking_rel_rms_pct_after'])
    assert s['recording_complete'] and not s['cut_short'] and not s['safety_faults']
    assert json.loads((out / 'summary.json').read_text())['actuators'] == s['actuators']


def test_the_interface_dofs_come_through_the_coupler(reviewed):
    s, truth, _ = reviewed
    x, theta = s['interface']
    assert (x['dof'], theta['dof']) == ('x', 'theta')
    assert x['max_abs_target'] == pytest.approx(np.max(np.abs(truth['x'])), rel=1e-6)
    assert theta['max_abs_target'] == pytest.approx(np.max(np.abs(truth['theta'])), rel=1e-6)
    # each DOF mixes both actuators' lags: its delay lies between them
    for dof in (x, theta):
        assert 1e3 * (LAG[0] - LEAD) / FS < dof['delay_ms_after'] < 1e3 * (LAG[1] - LEAD) / FS
    assert s['interface_max']['force_n'] > 0 and s['interface_max']['moment_n_m'] > 0
    assert 'rig file' in s['rig_source']


def test_the_text_and_the_page_show_both_actuators(reviewed):
    s, _, out = reviewed
    text = (out / 'review.txt').read_text()
    assert '1 lower' in text and '2 upper' in text and '\n  theta ' in text
    assert 'Tables 6-9' in text
    page = (out / 'report.html').read_text()
    for name in ('tracking_zoom_1.png', 'tracking_zoom_2.png', 'bode_actuator_1.png',
                 'bode_actuator_2.png', 'interface_dofs.png'):
        assert (out / name).stat().st_size > 10_000
        assert f'({name})' in page                         # embedded, with its caption
    assert '1: lower' in page and '2: upper' in page and '2 actuators' in page


def test_without_the_rig_file_the_models_coupler_is_used(tmp_path):
    from rths_review.review import review_rths
    bag, truth = write_bag(tmp_path, rig_file=tmp_path / 'gone.yaml')
    s = review_rths(bag, tmp_path / 'review')
    assert [a['name'] for a in s['actuators']] == ['actuator 1', 'actuator 2']
    assert 'gone.yaml is not there any more' in s['rig_source']
    # the benchmark's coupler is the rig file's geometry: the same interface motion
    assert s['interface'][0]['max_abs_target'] == pytest.approx(
        np.max(np.abs(truth['x'])), rel=1e-3)
    with pytest.raises(ValueError, match='drop --specimen-model and --dof'):
        review_rths(bag, tmp_path / 'r2', dof='x')
