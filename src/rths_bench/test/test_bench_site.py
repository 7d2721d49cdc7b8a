"""Interoperability: an unmodified OpenSeesPy genericClient model against ``rths site``.

The OpenSeesPy model (2-DOF building, CentralDifference, the genericClient element at the
top floor) runs in this process; ``rths site`` runs in its own (OpenSeesPy holds the GIL
in analyze()).  The same building and specimen run through rths lock-step in process.
"""

import json

import numpy as np
import pytest

from rths_bench import bench_site as bs
from rths_numerical.testing import require_opensees

STEPS = 400


@pytest.mark.parametrize('specimen', ['ideal', 'simulated'])
def test_opensees_genericclient_matches_rths_in_process(tmp_path, specimen):
    require_opensees()   # skips without OpenSeesPy, fails under CI=true
    result, extra = bs.bench_site(STEPS, specimen, tmp_path)
    assert tuple(result) == bs.FIELDS
    assert result['steps'] == STEPS - 1
    # identical loop steps: only the rounding of where the force enters OpenSees differs
    assert result['max_abs_diff_vs_direct'] < 1e-9
    # CentralDifference, Linear -factorOnce: setTrial x2, getForce, getDamp, commit per step
    assert result['messages_per_step'] == pytest.approx(5.0, abs=0.02)
    assert result['safety_state_final'] == 0
    assert extra['site_loop_steps'] == STEPS
    if specimen == 'ideal':   # rths on both sides (backend genericclient = --specimen tcp://)
        assert extra['tcp_specimen_max_abs_diff'] < 1e-9


def test_two_dof_model_is_tuned_near_the_dtm():
    f1 = bs.two_dof_model().dominant_frequencies(1)[0]
    assert 2.5 < f1 < 3.1   # the DTM's natural frequency is 2.81 Hz (seed Table 4)


def test_bench_json_has_exactly_the_issue_fields(tmp_path, monkeypatch):
    fake = dict.fromkeys(bs.FIELDS, 0)
    monkeypatch.setattr(bs, 'bench_site', lambda *a, **k: (fake, {}))
    monkeypatch.setattr('rths_numerical.opensees_backend.opensees_available',
                        lambda: (True, 'x'))
    from rths_bringup.cli import main
    out = tmp_path / 'site.json'
    assert main(['bench', 'site', '--out', str(out), '--steps', '2000', '--quiet']) == 0
    assert list(json.loads(out.read_text())) == list(bs.FIELDS)
    assert main(['bench', 'site', '--out', str(out), '--steps', '100']) == 2


def test_relative_diff():
    assert bs.relative_diff([1.0, 2.0], [1.0, 2.0]) == 0.0
    assert bs.relative_diff([1.0, 2.5], [1.0, 2.0]) == 0.25
    assert bs.relative_diff([np.nan], [1.0]) == float('inf')
