"""Issue 7 end to end: the discrepancy workflow names the friction of an RTHS's lab DTM.

The node graph runs in lock-step with the 2-story building (Kobe x 0.135, five
DTMs represented by one, ``force_scale: 5``) against the simulated plant,
whose DTM (valve #4, seed Table 4) has Coulomb friction on its moving mass
(``friction_n``) that the numerical reference lacks.  ``rths discrepancy``,
given the run's bag, must name ``coulomb_friction`` with the right force, and
the reference re-run with the updated specimen model must match the RTHS
better than the nominal one.  The bag carries the run's parameters as run
information (``rths launch --bag`` stores them, :mod:`rths_common.runinfo`),
so the nominal damper and the reference come from the bag; the ``--config``
passed as well is read only for a bag whose run information lacks them.
"""

import json

import numpy as np

from rths_system_tests import REPO, rths

#: Coulomb friction of the lab DTM [N]: mu ~ 0.012 on the 258 kg moving mass (Table 4).
FRICTION_N = 30.0
DURATION_S = 15.0


def _write_config(cfg):
    from rths_common import runinfo

    config = REPO / 'config'
    numerical = dict(runinfo.load_params(config / 'numerical.yaml', 'numerical'),
                     model='building2story', record='kobe', scale=0.135,
                     duration_s=DURATION_S, force_scale=5.0)
    for key in ('sdof_mass_kg', 'sdof_freq_hz', 'sdof_zeta'):
        numerical.pop(key, None)
    compensator = runinfo.load_params(config / 'compensator.yaml', 'compensator')
    bridge = dict(runinfo.load_params(config / 'bridge.yaml', 'bridge'), dtm='valve4',
                  friction_n=FRICTION_N)
    runinfo.write_params(cfg / 'numerical.yaml', 'numerical', numerical)
    runinfo.write_params(cfg / 'compensator.yaml', 'compensator', compensator)
    runinfo.write_params(cfg / 'bridge.yaml', 'bridge', bridge)


def test_workflow_names_lab_dtm_friction_and_updated_reference_matches_rths(tmp_path):
    from rths_discrepancy.io import read_bag
    from rths_numerical.dtm import TABLE4

    cfg = tmp_path / 'config'
    _write_config(cfg)
    bag = tmp_path / 'bag'
    rths('launch', '--config', cfg, '--bag', bag, timeout=300)

    # the DTM really works against the friction: its spring force dwarfs F_c and it
    # slides (|velocity| above the 1 mm/s friction velocity scale) most of the strong motion
    data = read_bag(bag, 'specimen')
    assert data['time'].size == int(DURATION_S * 1024)
    x = data['rel_disp']
    v = np.gradient(x, data['time'])
    assert TABLE4['valve4'].k_d * np.max(np.abs(x)) > 20 * FRICTION_N
    strong = (data['time'] > 3.0) & (data['time'] < 15.0)
    assert np.mean(np.abs(v[strong]) > 5e-3) > 0.5

    out = tmp_path / 'discrepancy'
    proc = rths('discrepancy', '--scenario', 'specimen', '--measured', bag, '--config', cfg,
                '--out', out, timeout=300)
    assert 'effect: coulomb_friction' in proc.stdout
    result = json.loads((out / 'result.json').read_text())
    assert result['effect'] == 'coulomb_friction'
    f_c = result['parameters']['coulomb_friction']['F_c']
    assert abs(f_c - FRICTION_N) <= 0.15 * FRICTION_N
    # the nominal model came from the run's damper; the updated one loads back
    assert result['updated_model']['c_d'] == TABLE4['valve4'].c_d
    assert (out / 'updated_model.yaml').is_file()

    # the proof: the reference with the updated specimen matches the RTHS far better
    ref = json.loads((out / 'reference.json').read_text())
    before = ref['rths_vs_nominal_reference_rel_rms_pct']
    after = ref['rths_vs_updated_reference_rel_rms_pct']
    assert before > 5.0           # friction of this size changes the building response
    assert after < 0.2 * before   # and the named effect accounts for (nearly) all of it
    assert after < 2.0
    assert 'updated specimen model (coulomb_friction' in proc.stdout

    # the stand-alone command gives the same numbers from the model file
    again = rths('reference', bag, '--specimen-model', out / 'updated_model.yaml',
                 '--config', cfg, '--out', tmp_path / 'ref', timeout=300)
    ref2 = json.loads((tmp_path / 'ref' / 'reference.json').read_text())
    assert abs(ref2['rths_vs_updated_reference_rel_rms_pct'] - after) < 1e-9 * max(after, 1)
    assert 'nominal specimen model' in again.stdout

    # the discrepancy report shows the re-run; the review takes the updated model and says so
    report = (out / 'report.md').read_text()
    assert '## The RTHS re-run with the updated model' in report
    assert f'{after:.3f} %' in report and f'{before:.3f} %' in report
    rths('review', bag, '--specimen-model', out / 'updated_model.yaml', '--out',
         tmp_path / 'review', timeout=300)
    summary = json.loads((tmp_path / 'review' / 'summary.json').read_text())
    assert abs(summary['rths_vs_reference_rel_rms_pct'] - after) < 1e-9 * max(after, 1)
    assert str(out / 'updated_model.yaml') in summary['reference_model']
    assert 'coulomb_friction' in (tmp_path / 'review' / 'review.txt').read_text()
