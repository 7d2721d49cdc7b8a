"""Bad input (issue 8): every params file, model file and ground-motion file.

Each broken file must give one clear error that names the file, the field and
the fix, before anything starts: ``rths launch`` checks every params file
first (:mod:`rths_bringup.preflight`), exits 2 and writes nothing (no bag).
"""

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from rths_system_tests import REPO, rths

CONFIG = REPO / 'config'


def write_config(directory: Path, node=None, changes=None, drop=()) -> Path:
    """Copy config/ with ``changes`` made to (and keys ``drop``ped from) ``node``'s file."""
    directory.mkdir(parents=True, exist_ok=True)
    for name in ('bridge', 'compensator', 'numerical'):
        data = yaml.safe_load((CONFIG / f'{name}.yaml').read_text())
        params = data[name]['ros__parameters']
        if name == node:
            params.update(changes or {})
            for key in drop:
                params.pop(key, None)
        (directory / f'{name}.yaml').write_text(yaml.safe_dump(data, sort_keys=False))
    return directory


def preflight_error(config) -> str:
    from rths_bringup.preflight import check_config

    with pytest.raises((ValueError, OSError)) as info:
        check_config(config)
    return str(info.value)


# (node, changes, words the message must hold: file name, field, fix)
PARAMS_CASES = [
    ('bridge', {'stroke_m': math.nan}, ['bridge.yaml', 'stroke_m', 'finite']),
    ('bridge', {'force_n': -1.0}, ['bridge.yaml', 'force_n', 'must be > 0']),
    ('bridge', {'stroke_m': 10.0}, ['bridge.yaml', 'stroke_m', 'inches or mm', 'give it in m']),
    ('bridge', {'stroke_m': '10 in'}, ['bridge.yaml', 'stroke_m', 'carries a unit']),
    ('bridge', {'stroke_mm': 254.0}, ['bridge.yaml', 'unknown parameter', 'stroke_mm',
                                      'known:']),
    ('bridge', {'velocity_m_s': math.inf}, ['bridge.yaml', 'velocity_m_s', 'finite']),
    ('bridge', {'backend': 'serial'}, ['bridge.yaml', 'backend', 'use one of']),
    ('compensator', {'taps': [1.0, math.nan]}, ['compensator.yaml', 'taps', 'nan']),
    ('compensator', {'taps': []}, ['compensator.yaml', 'taps', 'empty']),
    ('compensator', {'denominator': [1.0, -2.0]}, ['compensator.yaml', 'denominator',
                                                   'unstable']),
    ('compensator', {'fs_hz': '1024 Hz'}, ['compensator.yaml', 'fs_hz', 'carries a unit']),
    ('compensator', {'solver': 'lsi'}, ['compensator.yaml', 'unknown parameter', 'solver',
                                        "under 'provenance:'"]),
    ('compensator', {'fs_hz': 512.0}, ['compensator.yaml', 'fs_hz = 512 Hz', '1024 Hz',
                                       'design them for 1024 Hz']),
    ('numerical', {'fs_hz': math.nan}, ['numerical.yaml', 'fs_hz', 'finite']),
    ('numerical', {'scale': math.inf}, ['numerical.yaml', 'scale', 'finite']),
    ('numerical', {'duration': 5.0}, ['numerical.yaml', 'unknown parameter', 'duration',
                                      'known:']),
    ('numerical', {'sdof_mass_kg': -1000.0}, ['numerical.yaml', 'sdof_mass_kg', 'positive']),
    ('numerical', {'integrator': 'rk4'}, ['numerical.yaml', 'integrator', 'use one of']),
]


@pytest.mark.parametrize('node,changes,words', PARAMS_CASES,
                         ids=[f'{n}-{next(iter(c))}' for n, c, _ in PARAMS_CASES])
def test_bad_params_file_names_file_field_and_fix(tmp_path, node, changes, words):
    message = preflight_error(write_config(tmp_path / 'config', node, changes))
    for word in words:
        assert word in message, (word, message)


def test_broken_yaml_and_missing_section_are_named(tmp_path):
    config = write_config(tmp_path / 'config')
    (config / 'bridge.yaml').write_text('bridge:\n  ros__parameters:\n    stroke_m: [0.2\n')
    message = preflight_error(config)
    assert 'bridge.yaml' in message and 'not valid YAML' in message
    (config / 'bridge.yaml').write_text('brige:\n  ros__parameters: {}\n')
    message = preflight_error(config)
    assert 'bridge.yaml' in message and "expected 'bridge:'" in message


MODEL = {'M': [[1000.0, 0.0], [0.0, 1000.0]], 'K': [[2e6, -1e6], [-1e6, 1e6]],
         'damping': {'type': 'modal', 'zeta': 0.02}}

MODEL_CASES = [
    ({'K': [[2e6, -1e6], [-0.5e6, 1e6]]}, ['K', 'not symmetric', 'K[i][j] equal K[j][i]']),
    ({'M': [[1000.0, 0.0], [0.0, -1000.0]]}, ['M', 'not positive definite']),
    ({'K': [[2e6, -1e6], [-1e6, -1e6]]}, ['K', 'not positive definite']),
    ({'K': [[2e6, -1e6], [-1e6, math.nan]]}, ['K', 'finite']),
    ({'stiffness': [[1.0]]}, ['unknown key', 'stiffness', 'keys of a model file']),
    ({'M': [['1000 kg', 0.0], [0.0, 1000.0]]}, ['M', 'numbers in kg', 'no unit text']),
]


@pytest.mark.parametrize('change,words', MODEL_CASES, ids=[next(iter(c)) + str(i) for i, (c, _)
                                                           in enumerate(MODEL_CASES)])
def test_bad_building_model_file_is_named(tmp_path, change, words):
    model = tmp_path / 'frame.yaml'
    model.write_text(yaml.safe_dump(dict(MODEL, **change)))
    message = preflight_error(write_config(tmp_path / 'config', 'numerical',
                                           {'model': str(model)}))
    for word in ['frame.yaml', *words]:
        assert word in message, (word, message)


def test_good_building_model_file_passes(tmp_path):
    from rths_bringup.preflight import check_config

    model = tmp_path / 'frame.yaml'
    model.write_text(yaml.safe_dump(MODEL))
    check_config(write_config(tmp_path / 'config', 'numerical', {'model': str(model)}))


def write_dat(path, t, a):
    lines = ['event', 'source', 'station', 'band', 'Time[s] Accel[g]']
    lines += [f'{ti:.4f} {ai:.6f}' for ti, ai in zip(t, a, strict=True)]
    path.write_text('\n'.join(lines) + '\n')
    return path


def write_at2(path, values, npts, dt=0.01):
    body = [' '.join(f'{v:.6E}' for v in values[i:i + 5]) for i in range(0, len(values), 5)]
    path.write_text('\n'.join(['PEER NGA', 'event', 'ACCELERATION TIME SERIES IN UNITS OF G',
                               f'NPTS= {npts}, DT= {dt:.4f} SEC', *body]) + '\n')
    return path


def record_cases(tmp):
    t = np.arange(500) * 0.01
    a = 0.01 * np.sin(2 * np.pi * 2 * t)
    t_bad = t.copy()
    t_bad[200:] += 0.005                                    # one non-uniform step
    truncated = write_dat(tmp / 'cut.dat', t, a).read_text()
    (tmp / 'cut.dat').write_text(truncated[:-12])            # ends mid-line
    return [
        (write_dat(tmp / 'uneven.dat', t_bad, a), ['uneven.dat', 'not uniformly sampled',
                                                   'resample']),
        (tmp / 'cut.dat', ['cut.dat', 'truncated', 'restore']),
        (write_at2(tmp / 'short.AT2', a[:300], npts=500), ['short.AT2', 'NPTS=500', 'truncated']),
        (write_at2(tmp / 'nan.AT2', np.r_[a[:10], math.nan, a[11:]], npts=500),
         ['nan.AT2', 'nan']),
    ]


def test_bad_ground_motion_files_are_named(tmp_path):
    for path, words in record_cases(tmp_path):
        message = preflight_error(write_config(tmp_path / f'config-{path.stem}', 'numerical',
                                               {'record': str(path), 'scale': 0.1}))
        for word in words:
            assert word in message, (word, message)


def test_good_ground_motion_file_passes(tmp_path):
    from rths_bringup.preflight import check_config

    t = np.arange(500) * 0.01
    good = write_at2(tmp_path / 'good.AT2', 0.01 * np.sin(2 * np.pi * 2 * t), npts=500)
    check_config(write_config(tmp_path / 'config', 'numerical',
                              {'record': str(good), 'scale': 0.1, 'duration_s': 1.0}))


def test_launch_with_a_bad_file_exits_2_and_writes_nothing(tmp_path):
    config = write_config(tmp_path / 'config', 'bridge', {'acceleration_m_s2': math.nan})
    bag = tmp_path / 'bag'
    proc = rths('launch', '--config', config, '--bag', bag, check=False, timeout=120)
    assert proc.returncode == 2
    assert 'rths launch: error:' in proc.stderr
    assert 'bridge.yaml' in proc.stderr and 'acceleration_m_s2' in proc.stderr
    assert 'started' not in proc.stdout      # no node was started
    assert not bag.exists()                  # nothing half-written
