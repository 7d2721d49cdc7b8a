"""The maRTHS benchmark's numerical substructure behind the numerical node (``model: marths``).

Numbers: the benchmark's public code (github.com/FermandoisLab/maRTHS-bmk-RoDeAC, MIT;
``build_reference.m``, ``build_numerical.m``, ``build_physical_ideal.m``), in
rths_common/data/marths.json.
"""

import numpy as np
import pytest

from rths_common.marths_data import load_config, rig_coupler
from rths_numerical import marths as nm
from rths_numerical.stepping import NumericalCore
from rths_numerical.substructure import make_substructure

CFG = load_config()
FS = 1024.0


def _pulse(n=1024):
    t = np.arange(n) / FS
    return 2.0 * np.sin(2 * np.pi * 2.0 * t) * np.sin(np.pi * t / t[-1])


def _newmark_run(ag, forces):
    """Run the offline loop's numerical structure by hand: Newmark, force on x and theta."""
    num = nm.Newmark(*nm.numerical_matrices(CFG), 1.0 / FS, 1)
    d = nm.story_dofs(CFG)
    out = []
    for k, a in enumerate(ag):
        f = np.zeros((1, num.u.shape[1]))
        if k:
            f[0, d['x']], f[0, d['theta']] = forces[k - 1]
        out.append(num.step(a, f)[0].copy())
    return np.array(out)


def test_the_strokes_are_the_newmark_structure_through_the_coupler():
    ag = _pulse()
    sub = nm.MarthsSubstructure(ag, 1.0 / FS)
    assert sub.n_interface == 2 and sub.n_steps == ag.size
    coupler = rig_coupler(CFG)
    theta = sub.dofs['theta']
    # two axial forces whose force and moment at the node (at the commanded rotation) are
    # known: the substructure must apply exactly those on x and theta
    rng = np.random.default_rng(3)
    axial = 200.0 * rng.standard_normal((ag.size, 2))
    strokes = [sub.first_displacement()]
    applied = []
    for k in range(ag.size - 1):
        th = coupler.dofs(strokes[k], iterations=8)[1]   # the commanded rotation
        fx, mom = coupler.interface_forces(axial[k], th)
        applied.append((fx, -mom))
        strokes.append(sub.advance(axial[k]))
    d = _newmark_run(ag, applied)
    want = coupler.strokes(d[:, sub.dofs['x']], -d[:, theta]).T
    assert np.max(np.abs(np.array(strokes) - want)) <= 1e-9 * np.max(np.abs(want))
    assert np.max(np.abs(want)) > 1e-4                   # the structure moved (> 0.1 mm)
    hist = sub.history()
    assert hist['command'].shape == (ag.size - 1, 2)
    assert np.allclose(hist['x_num'], d[:-1, sub.dofs['x']])


def test_the_node_parameters_build_it_from_a_record_file(tmp_path):
    t = np.arange(2048) / FS
    path = tmp_path / 'pulse.txt'
    np.savetxt(path, np.column_stack([t, np.r_[_pulse(1024), np.zeros(1024)]]))
    sub = make_substructure({'model': 'marths', 'record': str(path), 'fs_hz': FS, 'scale': 1.0,
                             'record_units': 'm/s^2', 'record_resample': False,
                             'record_remove_mean': False, 'record_baseline': False})
    assert isinstance(sub, nm.MarthsSubstructure) and sub.n_steps == 2048
    core = NumericalCore(sub)
    out = core.step(0, np.zeros(2))
    assert out.output.shape == (2,)
    with pytest.raises(ValueError, match='2 finite value'):
        core.step(1, np.zeros(3))


@pytest.mark.parametrize('extra, match', [({'record': 'harmonic'}, 'give a record file'),
                                          ({'backend': 'opensees'}, 'builtin backend')])
def test_marths_needs_a_record_and_the_builtin_backend(extra, match):
    with pytest.raises(ValueError, match=match):
        make_substructure({'model': 'marths', 'record': 'kobe', **extra})
