"""Where the data sets are found (rths_common.datasets); the CI rule (rths_common.testing)."""

import os
import subprocess
import sys
import textwrap

import pytest

from rths_common import datasets, testing


def _shared_beside(tmp_path, with_emps=True):
    """Make a fake checkout ``tmp/repo`` with ``tmp/shared/data/emps`` beside it."""
    repo = tmp_path / 'repo'
    repo.mkdir()
    data = tmp_path / 'shared' / 'data'
    (data / 'emps').mkdir(parents=True)
    if with_emps:
        for name in datasets.DATASETS['emps'].files:
            (data / 'emps' / name).write_text('')
    return repo, data


def test_default_is_shared_data_beside_the_repository(tmp_path, monkeypatch):
    repo, data = _shared_beside(tmp_path)
    monkeypatch.setenv('RTHS_ROOT', str(repo))
    monkeypatch.delenv('RTHS_DATA_DIR', raising=False)
    assert datasets.data_dir() == data.resolve()
    assert datasets.missing('emps') is None
    assert datasets.dataset_dir('emps') == data.resolve() / 'emps'


def test_a_users_rths_data_dir_wins(tmp_path, monkeypatch):
    repo, _ = _shared_beside(tmp_path)
    own = tmp_path / 'mine'
    monkeypatch.setenv('RTHS_ROOT', str(repo))
    monkeypatch.setenv('RTHS_DATA_DIR', str(own))
    assert datasets.data_dir() == own
    reason = datasets.missing('emps')
    assert reason and f'RTHS_DATA_DIR={own}' in reason


def test_no_data_anywhere_is_a_one_line_reason_naming_set_source_and_fix(tmp_path, monkeypatch):
    monkeypatch.setenv('RTHS_ROOT', str(tmp_path / 'repo'))
    monkeypatch.delenv('RTHS_DATA_DIR', raising=False)
    assert datasets.data_dir() is None
    reason = datasets.missing('mr_damper')
    assert '\n' not in reason
    for part in ("data set 'mr_damper'", '2mm5Hz1A.txt', 'vRTHS_AMBC_MRdamper', 'MIT',
                 'RTHS_DATA_DIR=DIR', 'shared'):
        assert part in reason
    with pytest.raises(OSError, match="data set 'mr_damper'"):
        datasets.dataset_dir('mr_damper')


def test_a_partial_data_set_names_the_missing_file(tmp_path, monkeypatch):
    repo, data = _shared_beside(tmp_path, with_emps=False)
    (data / 'emps' / 'DATA_EMPS.mat').write_text('')
    monkeypatch.setenv('RTHS_ROOT', str(repo))
    monkeypatch.delenv('RTHS_DATA_DIR', raising=False)
    assert 'no DATA_EMPS_PULSES.mat under' in datasets.missing('emps')


def test_the_repository_is_found_without_rths_root(monkeypatch):
    monkeypatch.delenv('RTHS_ROOT', raising=False)
    root = datasets.repo_root()
    assert root is not None and (root / 'src' / 'rths_common').is_dir()


def _pytest(tmp_path, ci, env_extra, body):
    test = tmp_path / 'test_probe.py'
    test.write_text(textwrap.dedent(body))
    env = {k: v for k, v in os.environ.items() if k != 'CI'}
    env.update(env_extra)
    if ci:
        env['CI'] = 'true'
    return subprocess.run([sys.executable, '-m', 'pytest', '-q', '-rfEs', '-p', 'no:cacheprovider',
                           str(test)], capture_output=True, text=True, env=env, timeout=120,
                          cwd=tmp_path)


PROBE = '''
from rths_common.testing import require_data
def test_needs_emps():
    require_data('emps')
def test_needs_benchmark_records():
    require_data('silva2020_records')
'''


def test_missing_data_skips_outside_ci_and_fails_in_ci(tmp_path):
    """Outside CI: two skips with the reason. CI=true: the redistributable set fails, one line."""
    env = {'RTHS_ROOT': str(tmp_path / 'repo'), 'RTHS_DATA_DIR': str(tmp_path / 'none')}
    out = _pytest(tmp_path, False, env, PROBE)
    assert out.returncode == 0 and '2 skipped' in out.stdout, out.stdout
    assert "data set 'emps'" in out.stdout
    out = _pytest(tmp_path, True, env, PROBE)
    assert out.returncode == 1 and '1 failed, 1 skipped' in out.stdout, out.stdout
    line = next(ln for ln in out.stdout.splitlines() if ln.startswith('FAILED'))
    assert "data set 'emps'" in line and 'forgi86/sysid-neural-continuous' in line
    assert 'CI=true' in line
    assert 'may not be redistributed' in out.stdout


def test_require_passes_when_available_and_reads_ci(monkeypatch):
    testing.require(True, 'unused')
    for value, expected in (('true', True), ('1', True), ('', False), ('false', False)):
        monkeypatch.setenv('CI', value)
        assert testing.in_ci() is expected
