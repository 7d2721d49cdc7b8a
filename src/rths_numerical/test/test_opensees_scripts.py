"""The user-script contract of the OpenSees backend: a model script and its clear errors."""

import textwrap

import numpy as np
import pytest

from rths_numerical.substructure import make_substructure
from rths_numerical.testing import require_opensees


@pytest.fixture(autouse=True)
def _opensees():
    """Every test here builds an OpenSees model: skip without OpenSeesPy, fail in CI."""
    require_opensees()


SDOF = '''
def build(ops):
    ops.model('basic', '-ndm', 1, '-ndf', 1)
    ops.node(1, 0.0)
    ops.node(2, 0.0, '-mass', 1000.0)
    ops.fix(1, 1)
    ops.uniaxialMaterial('Elastic', 1, 1000.0 * (2 * 3.141592653589793 * 2.0) ** 2, 500.0)
    ops.element('zeroLength', 1, 1, 2, '-mat', 1, '-dir', 1)
    return {RESULT}
'''


def _script(tmp_path, body=None, result="{'interface_node': 2, 'interface_dof': 1}"):
    path = tmp_path / 'model.py'
    path.write_text(textwrap.dedent(body if body is not None else SDOF.replace('{RESULT}',
                                                                               result)))
    return str(path)


def _params(path, **extra):
    return dict({'backend': 'opensees', 'model': path, 'record': 'kobe', 'scale': 0.1,
                 'duration_s': 2.0, 'fs_hz': 1024.0}, **extra)


def test_a_script_sdof_equals_the_builtin_sdof(tmp_path):
    """The same SDOF (1000 kg, 2 Hz, c = 500 N s/m) as a script and as the built-in model."""
    zeta = 500.0 / (2 * 1000.0 * 2 * np.pi * 2.0)
    runs = []
    for params in (_params(_script(tmp_path)),
                   {'backend': 'builtin', 'integrator': 'central_difference', 'model': 'sdof',
                    'sdof_mass_kg': 1000.0, 'sdof_freq_hz': 2.0, 'sdof_zeta': zeta,
                    'record': 'kobe', 'scale': 0.1, 'duration_s': 2.0, 'fs_hz': 1024.0}):
        sub = make_substructure(params)
        cmd = sub.first_displacement()
        while not sub.done():
            cmd = sub.advance(np.array([200.0 * cmd[0]]))
        runs.append(sub.history()['output_disp'])
    err = np.sqrt(np.mean((runs[0] - runs[1]) ** 2) / np.mean(runs[1] ** 2))
    assert err < 1e-3


@pytest.mark.parametrize('body, result, match', [
    ('x = 1\n', None, r'define a function build\(ops\)'),
    ('def build(ops):\n    raise KeyError("E")\n', None, r'build\(ops\) failed: KeyError'),
    ('import no_such_module_xyz\n', None, 'importing it failed'),
    (None, '[2, 1]', 'a dict with interface_node'),
    (None, "{'interface_dof': 1}", 'integer interface_node'),
    (None, "{'interface_node': 7, 'interface_dof': 1}", 'node 7 is not in the model'),
    (None, "{'interface_node': 2, 'interface_dof': 3}", r'interface_dof in 1\.\.1'),
    (None, "{'interface_node': 2, 'interface_dof': 1, 'hinge': (9, 1)}", 'hinge'),
])
def test_a_script_that_breaks_the_contract_is_refused_clearly(tmp_path, body, result, match):
    path = _script(tmp_path, body, result) if body is None else _script(tmp_path, body)
    with pytest.raises(ValueError, match=match) as err:
        make_substructure(_params(path))
    assert path in str(err.value)


def test_script_needs_the_opensees_backend_and_an_existing_file(tmp_path):
    with pytest.raises(ValueError, match='backend: opensees'):
        make_substructure(dict(_params(_script(tmp_path)), backend='builtin'))
    with pytest.raises(ValueError, match='not found'):
        make_substructure(_params(str(tmp_path / 'missing.py')))


def test_the_shipped_frame_yields_and_records_its_hinge():
    """config/models/frame_steel01.py under Kobe x 0.135 (6 s): the hinge yields.

    Its moment passes the yield moment (8 kN m) and its loop dissipates energy.
    """
    import os
    root = os.path.join(os.path.dirname(__file__), '..', '..', '..')
    path = os.path.join(root, 'config', 'models', 'frame_steel01.py')
    sub = make_substructure(_params(path, scale=0.135, duration_s=6.0))
    while not sub.done():
        sub.advance(np.zeros(1))
    h = sub.history()
    assert np.max(np.abs(h['hinge_moment'])) > 8e3
    # energy dissipated by the hinge: the loop's enclosed area is positive
    work = np.sum(h['hinge_moment'][1:] * np.diff(h['hinge_rotation']))
    assert work > 0
