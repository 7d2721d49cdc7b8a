"""The SPEC: expansion into runs, keys, seeds, and errors that name the field."""

from pathlib import Path

import numpy as np
import pytest

from rths_study.spec import check_spec, load_spec

CONFIG = Path(__file__).resolve().parents[3] / 'config' / 'studies'


def _spec(**fields):
    raw = {'study': 't', 'scenario': {'kind': 'cluster-check'}}
    raw.update(fields)
    return check_spec(raw)


def test_grid_is_the_product_in_spec_order_with_evenly_spaced_axes():
    spec = _spec(parameters={'grid': {'x': {'start': 0, 'stop': 1, 'num': 3}, 'y': [5, 7]}})
    assert spec.layout == 'grid'
    assert spec.axes == {'x': [0.0, 0.5, 1.0], 'y': [5.0, 7.0]}
    assert [(r.params['x'], r.params['y']) for r in spec.runs()] == [
        (0.0, 5.0), (0.0, 7.0), (0.5, 5.0), (0.5, 7.0), (1.0, 5.0), (1.0, 7.0)]
    assert [r.index for r in spec.runs()] == list(range(6))


def test_random_draws_are_seeded_per_point_so_more_draws_keep_the_first():
    draws = {'x': {'normal': {'mean': 10.0, 'std': 2.0}},
             'y': {'uniform': {'low': -1.0, 'high': 1.0}}}
    small = _spec(parameters={'random': {'n': 3, 'seed': 4, 'draws': draws}})
    large = _spec(parameters={'random': {'n': 400, 'seed': 4, 'draws': draws}})
    assert small.points == large.points[:3]
    assert [r.key for r in small.runs()] == [r.key for r in large.runs()[:3]]
    x = np.array([p['x'] for p in large.points])
    y = np.array([p['y'] for p in large.points])
    assert abs(x.mean() - 10.0) < 0.4 and abs(x.std() - 2.0) < 0.4
    assert y.min() >= -1.0 and y.max() <= 1.0
    other = _spec(parameters={'random': {'n': 3, 'seed': 5, 'draws': draws}})
    assert other.points != small.points


def test_keys_hash_every_input_and_controllers_share_the_noise_seed():
    spec = check_spec({'study': 't', 'scenario': {'kind': 'benchmark'},
                       'parameters': {'list': [{'b1': 420.0}, {'b1': 430.0}]},
                       'controllers': ['example', 'fir'], 'records': ['gmspy:kobe']})
    runs = spec.runs()
    assert len(runs) == 4 and len({r.key for r in runs}) == 4
    assert runs[0].seed == runs[1].seed != runs[2].seed        # same plant, both controllers
    again = check_spec(dict(spec.raw))
    assert [r.key for r in again.runs()] == [r.key for r in runs]
    moved = check_spec(dict(spec.raw, scenario={'kind': 'benchmark', 'duration_s': 5.0}))
    assert not {r.key for r in moved.runs()} & {r.key for r in runs}


@pytest.mark.parametrize('fields, message', [
    ({'colour': 1}, 'colour: unknown field'),
    ({'scenario': {'kind': 'weather'}}, 'scenario.kind'),
    ({'scenario': {'kind': 'cluster-check', 'wrok': 1}}, 'scenario.wrok: unknown'),
    ({'scenario': {'kind': 'cluster-check', 'work': 0}}, 'scenario.work: 0 is below'),
    ({'parameters': {'grid': {'z': [1]}}}, 'parameters.grid.z: not a parameter'),
    ({'parameters': {'grid': {'x': [1, 1]}}}, 'parameters.grid.x: a value appears twice'),
    ({'parameters': {'grid': {'x': ['a']}}}, r'parameters.grid.x\[0\]: expected a number'),
    ({'parameters': {'random': {'n': 2, 'draws': {'x': {'gamma': {}}}}}},
     'parameters.random.draws.x: expected'),
    ({'parameters': {'random': {'n': 2, 'draws': {'x': {'normal': {'mean': 1}}}}}},
     'parameters.random.draws.x.normal: give mean and std'),
    ({'parameters': {'grid': {'x': [1]}, 'list': []}}, 'exactly one of grid, random, list'),
    ({'parameters': {'list': [{'x': 1}, {'y': 2}]}}, r'parameters.list\[1\]'),
    ({'controllers': ['fir']}, 'controllers: this scenario takes none'),
    ({'metrics': ['J1']}, r'metrics\[0\]'),
    ({'execution': {'chunk': 0}}, 'execution.chunk'),
])
def test_a_bad_field_is_refused_naming_it(fields, message):
    with pytest.raises(ValueError, match=message):
        _spec(**fields)


def test_a_missing_benchmark_record_names_the_fix(monkeypatch, tmp_path):
    monkeypatch.setenv('RTHS_DATA_DIR', str(tmp_path))
    with pytest.raises(ValueError, match=r'records\[0\].*ElCentroAccelNoScaling.mat'):
        check_spec({'study': 't', 'scenario': {'kind': 'benchmark'}, 'records': ['elcentro']})


def test_yaml_exponents_without_a_dot_are_numbers(tmp_path):
    # PyYAML reads 1e6 (no dot, no sign) as text; the SPEC takes it as the number
    path = tmp_path / 'spec.yaml'
    path.write_text('study: t\nscenario: {kind: cluster-check, work: 1e3}\n')
    assert load_spec(path).settings['work'] == 1000
    with pytest.raises(OSError, match='no such SPEC file'):
        load_spec(tmp_path / 'missing.yaml')
    path.write_text('study: [unclosed\n')
    with pytest.raises(ValueError, match='not valid YAML'):
        load_spec(path)


def test_every_shipped_spec_loads():
    specs = sorted(CONFIG.glob('*.yaml'))
    assert len(specs) >= 5
    counts = {p.stem: len(load_spec(p).runs()) for p in specs}
    assert counts['benchmark_perturbed'] == 2000
    assert counts['dtm_tuning'] == 199 * 30          # rths study dtm-tuning's default grid
    assert counts['building_frequency'] == 40 * 26   # rths study building-frequency's
