"""``rths bench compensators`` in miniature: JSON layout of issue 3 and the targets() logic.

The study (:func:`rths_compensator.bench.run_study`) runs here on a tiny configuration
(3 FIR designs, ARX grid 3 x 3, records of a few seconds, 200 timed filter steps), so a
renamed or missing key shows up without the full one-minute run.  Its numbers are not
checked here (short noisy records); the bench itself measures them.
"""

import copy
import json

import numpy as np
import pytest

from rths_compensator import bench
from rths_compensator import design as dsg

BAND_KEYS = [str(b) for b in bench.BANDS_HZ]
COMPARISON_NAMES = (
    [f'inverse-tau{b}hz' for b in bench.BANDS_HZ]
    + [f'mff-{kind}-alpha{alpha}' for kind in ('3pole', '4pole') for alpha in (3, 5, 7)]
    + ['npz-ignore', 'zpetc', 'zmetc'])


@pytest.fixture(scope='module')
def tiny(tmp_path_factory):
    """Return (result, JSON as read back, log lines) of a tiny study."""
    logs = []
    result = bench.run_study(seed=3, eval_s=8.0, taps_list=(100,), fc_list=(64,),
                             n_validation=4, na_max=3, nb_max=3, train_s=3.0, val_s=3.0,
                             node_steps=200, log=logs.append)
    path = tmp_path_factory.mktemp('bench') / 'compensators.json'
    bench.write_json(path, result)
    with open(path, encoding='utf-8') as handle:
        return result, json.load(handle), logs


def _check_bands(bands, where):
    assert sorted(bands, key=int) == BAND_KEYS, where
    for key in BAND_KEYS:
        assert set(bands[key]) == {'delay_ms', 'rel_rms_pct'}, where
        assert all(np.isfinite(v) for v in bands[key].values()), where


def test_json_layout(tiny):
    """The layout issue 3 specifies, and no private ``_extra`` in the file."""
    _, doc, _ = tiny
    for key in ('uncompensated', 'compensators', 'fir_design_total_s', 'arx_selection_s',
                'unstable_zero_fs_hz', 'node_step_us_400taps'):
        assert key in doc, key
    assert not any(key.startswith('_') for key in doc)
    _check_bands(doc['uncompensated']['bands'], 'uncompensated')
    assert set(doc['unstable_zero_fs_hz']) == {'3pole', '4pole'}
    for key in ('fir_design_total_s', 'arx_selection_s', 'node_step_us_400taps'):
        assert isinstance(doc[key], float) and doc[key] > 0, key
    assert doc['identified_model']['zero_tol'] == bench.BENCH_ZERO_TOL
    for entry in doc['compensators']:
        assert {'name', 'scheme', 'taps', 'fc_hz', 'design_s', 'bands'} <= set(entry)
        assert entry['scheme'] in dsg.ALL_SCHEMES
        assert isinstance(entry['design_s'], float)
        if entry['scheme'] in dsg.FIR_SCHEMES:
            assert isinstance(entry['taps'], int) and isinstance(entry['fc_hz'], int)
        else:
            assert entry['taps'] is None and entry['fc_hz'] is None
        if entry['bands'] is None:
            assert entry['error'], entry['name']
        else:
            _check_bands(entry['bands'], entry['name'])


def test_every_design_is_named_once(tiny):
    _, doc, logs = tiny
    names = [c['name'] for c in doc['compensators']]
    assert len(names) == len(set(names))
    fir = [f'fir-{s}-n100-fc64' for s in dsg.FIR_SCHEMES]
    assert names == fir + COMPARISON_NAMES
    by_name = {c['name']: c for c in doc['compensators']}
    assert by_name['fir-mm-n100-fc64']['taps'] == 100
    assert by_name['fir-mm-n100-fc64']['fc_hz'] == 64
    assert not any('FAILED' in line for line in logs), logs   # progress shown, no failure
    assert any(line.startswith('[4/4]') for line in logs)


def test_targets_rows_of_the_tiny_run(tiny):
    result, doc, _ = tiny
    rows = bench.targets(result)
    assert rows == bench.targets(doc)              # works on the JSON as well
    # 4 uncompensated delays, 4 LS delays, 2 x 3 RMS rows, 3 time limits, 2 Appendix I
    assert len(rows) == 19
    for name, measured, limit, ok in rows:
        assert isinstance(name, str) and isinstance(measured, str) and isinstance(limit, str)
        assert isinstance(ok, (bool, np.bool_))
    names = [r[0] for r in rows]
    assert sum('FIR LS n=100 fc=64 delay' in n for n in names) == 4
    assert 'node step, 400 taps' in names


def test_make_plots_of_the_tiny_run(tiny, tmp_path):
    result, _, _ = tiny
    files = bench.make_plots(result, str(tmp_path / 'plots'))
    assert len(files) == 6
    for path in files:
        with open(path, 'rb') as handle:
            assert handle.read(8) == b'\x89PNG\r\n\x1a\n'


def _synthetic():
    """Return a result in the JSON layout where every target holds."""
    bands = {str(b): {'delay_ms': bench.SEED_TABLE2_DELAY_MS[b], 'rel_rms_pct': 30.0}
             for b in bench.BANDS_HZ}

    def entry(name, scheme, taps, fc, delay, rms):
        return {'name': name, 'scheme': scheme, 'taps': taps, 'fc_hz': fc, 'design_s': 0.1,
                'bands': {str(b): {'delay_ms': delay, 'rel_rms_pct': rms}
                          for b in bench.BANDS_HZ}}

    return {'uncompensated': {'bands': bands},
            'compensators': [entry('fir-ls-n100-fc64', 'ls', 100, 64, 0.05, 2.0),
                             entry('fir-mm-n100-fc64', 'mm', 100, 64, 0.05, 3.0),
                             entry('zpetc', 'zpetc', None, None, 4.0, 20.0),
                             {**entry('fir-mm-n300-fc128', 'mm', 300, 128, 0, 0),
                              'bands': None, 'error': 'failed'}],
            'fir_design_total_s': 30.0, 'fir_design_cpu_s': 29.0, 'arx_selection_s': 20.0,
            'unstable_zero_fs_hz': {'3pole': 41.2, '4pole': 42.3},
            'node_step_us_400taps': 3.0}


def _oks(result):
    return {name: ok for name, _, _, ok in bench.targets(result)}


def test_targets_logic():
    """Each target's verdict follows its limit (issue 3, seed Table 2 and Appendix I)."""
    base = _synthetic()
    oks = _oks(base)
    assert all(oks.values()), oks
    lowest = 'FIR LS n=100 fc=64 lowest rel. RMS 0-20 Hz of all'
    lower = 'FIR LS n=100 fc=64 lower rel. RMS than every non-FIR 0-20 Hz'

    r = copy.deepcopy(base)                 # another FIR beats LS: 'lowest of all' fails
    r['compensators'][1]['bands']['20']['rel_rms_pct'] = 1.0
    oks = _oks(r)
    assert not oks[lowest] and oks[lower]
    r = copy.deepcopy(base)                 # a non-FIR beats LS: both fail
    r['compensators'][2]['bands']['20']['rel_rms_pct'] = 1.5
    oks = _oks(r)
    assert not oks[lowest] and not oks[lower]

    cases = [  # (path to the value, new value, target name)
        (('uncompensated', 'bands', '5', 'delay_ms'), 14.9 + 1.6,
         'uncompensated delay 0-5 Hz vs Table 2 14.9 ms'),
        (('compensators', 0, 'bands', '30', 'delay_ms'), -0.11,
         'FIR LS n=100 fc=64 delay 0-30 Hz'),
        (('compensators', 0, 'bands', '20', 'rel_rms_pct'), 5.1,
         'FIR LS n=100 fc=64 rel. RMS 0-20 Hz'),
        (('compensators', 0, 'bands', '30', 'rel_rms_pct'), 10.1,
         'FIR LS n=100 fc=64 rel. RMS 0-30 Hz'),
        (('fir_design_total_s',), 60.5, '72 FIR designs total'),
        (('arx_selection_s',), 61.0, 'ARX grid + selection'),
        (('node_step_us_400taps',), 20.5, 'node step, 400 taps'),
        (('unstable_zero_fs_hz', '4pole'), 43.5, 'Appendix I threshold 4pole vs seed ~42 Hz')]
    for path, value, name in cases:
        r = copy.deepcopy(base)
        node = r
        for key in path[:-1]:
            node = node[key]
        node[path[-1]] = value
        oks = _oks(r)
        assert not oks[name], name
        assert sum(not ok for ok in oks.values()) <= 2, (name, oks)


def test_targets_without_the_ls_design():
    """A failed or missing LS n=100 fc=64 design drops its rows instead of crashing."""
    r = _synthetic()
    r['compensators'] = r['compensators'][1:]
    names = [row[0] for row in bench.targets(r)]
    assert not any('FIR LS' in n for n in names)
    assert '72 FIR designs total' in names
