"""A run bag in the restoring-force contract: ``rths bag export`` and ``--measured BAG``.

The bag is written as the recorder writes a run (``/rths/measurement`` with the
measured displacement and force, run information with ``fs_hz``) and holds a
linear spring-damper with Coulomb friction (20 N), so the analysis has an
effect to name from the bag.
"""

import json

import numpy as np
import pytest

FS_HZ = 256.0
DURATION_S = 12.0
K, C, FC = 2.0e4, 300.0, 20.0


@pytest.fixture(scope='module')
def run_dir(tmp_path_factory):
    """Write a results directory holding its RTHS bag at rths/bag."""
    from rths_common import bagio, runinfo, topics

    t = np.arange(int(DURATION_S * FS_HZ)) / FS_HZ
    x = 5e-3 * np.sin(2 * np.pi * 1.3 * t) + 2e-3 * np.sin(2 * np.pi * 3.1 * t)
    v = np.gradient(x, 1 / FS_HZ)
    force = K * x + C * v + FC * np.tanh(v / 1e-3)
    store = bagio.typestore()
    meas = store.types['rths_msgs/msg/Measurement']
    header = store.types['std_msgs/msg/Header']
    stamp = store.types['builtin_interfaces/msg/Time']
    info = runinfo.flatten('rths', FS_HZ, 'lockstep', {'bridge': {'specimen': 'mr'}})
    out = tmp_path_factory.mktemp('run')
    with bagio.BagWriter(out / 'rths' / 'bag', run_info=info) as writer:
        for k in range(t.size):
            t_ns = int(round(k * 1e9 / FS_HZ))
            msg = meas(header=header(stamp=stamp(sec=t_ns // 10**9, nanosec=t_ns % 10**9),
                                     frame_id=''),
                       step=k, applied=np.array([x[k]]), displacement=np.array([x[k]]),
                       force=np.array([force[k]]))
            writer.write_msg(topics.MEASUREMENT, t_ns, msg)
    return out, x, force


def test_bag_export_writes_the_restoring_force_columns(run_dir, tmp_path, capsys):
    from rths_bringup.cli import main
    from rths_discrepancy import restoring

    out, x, force = run_dir
    csv = tmp_path / 'mr.csv'
    assert main(['bag', 'export', str(out / 'rths' / 'bag'), '--out', str(csv)]) == 0
    assert 'time_s, displacement_m, force_N' in capsys.readouterr().out
    data = restoring.load_csv(csv)
    assert data['fs'] == pytest.approx(FS_HZ)
    np.testing.assert_allclose(data['displacement_m'], x, rtol=1e-9, atol=1e-14)
    np.testing.assert_allclose(data['force_N'], force, rtol=1e-9, atol=1e-9)


def test_the_results_directory_instead_of_the_bag_names_the_bag(run_dir, tmp_path, capsys):
    from rths_bringup.cli import main

    out, _, _ = run_dir
    assert main(['bag', 'export', str(out), '--out', str(tmp_path / 'x.csv')]) == 2
    err = capsys.readouterr().err
    assert 'is a results directory, not a bag' in err
    assert str(out / 'rths' / 'bag') in err


def test_a_specimen_without_table_mass_is_analysed_from_its_bag(run_dir, tmp_path):
    """--scenario specimen on a run of the MR damper goes to the restoring-force analysis."""
    from rths_bringup.cli import main

    out, _, _ = run_dir
    res_dir = tmp_path / 'disc'
    assert main(['discrepancy', '--scenario', 'specimen', '--measured',
                 str(out / 'rths' / 'bag'), '--out', str(res_dir)]) == 0
    res = json.loads((res_dir / 'result.json').read_text())
    assert res['effect'] == 'coulomb_friction'
    assert res['parameters']['coulomb_friction']['F_c'] == pytest.approx(FC, rel=0.15)
