"""CausalFilter / MultiChannelFilter against scipy.signal.lfilter; the parameters file."""

import numpy as np
import pytest
from scipy import signal
import yaml

from rths_compensator.filters import CausalFilter, MultiChannelFilter
from rths_compensator.params import (
    identity_params,
    load_compensator_params,
    write_compensator_params,
)


@pytest.mark.parametrize('nb, den', [(1, [1.0]), (400, [1.0]), (7, [2.0, -0.9, 0.2]),
                                     (3, [1.0, -1.2, 0.5, -0.1])])
def test_causal_filter_equals_lfilter(nb, den):
    rng = np.random.default_rng(nb)
    taps = rng.standard_normal(nb)
    x = rng.standard_normal(3000)
    ref = signal.lfilter(taps, den, x)
    filt = CausalFilter(taps, den)
    out = filt.apply(x)
    assert np.max(np.abs(out - ref)) <= 1e-12 * max(1.0, np.max(np.abs(ref)))
    filt.reset()
    step = np.array([filt.step(v) for v in x[:50]])
    np.testing.assert_allclose(step, ref[:50], rtol=0, atol=1e-12 * np.max(np.abs(ref)))


def test_multichannel_equals_lfilter_per_channel():
    rng = np.random.default_rng(3)
    taps, den = rng.standard_normal(9), [1.0, -0.5, 0.06]
    x = rng.standard_normal((500, 3))
    filt = MultiChannelFilter(taps, den, 3)
    out = np.array([filt.step(row) for row in x])
    np.testing.assert_allclose(out, signal.lfilter(taps, den, x, axis=0), atol=1e-12)
    with pytest.raises(ValueError):
        filt.step(np.zeros(2))


@pytest.mark.parametrize('nb', [1, 5, 15, 16, 35, 206])
@pytest.mark.parametrize('na', [0, 1, 4, 15, 20])
def test_causal_filter_is_a_one_channel_multichannel_filter_bit_for_bit(nb, na):
    """The scalar path (Python floats, numpy.dot from 16 coefficients) sums as numpy does.

    A 4th-order low-pass at 4096 Hz turns a one-ulp change of a sum into 1e-10 of its
    output; the adaptive methods' outputs must not change (test_adaptive_equivalence).
    """
    rng = np.random.default_rng(nb * 100 + na)
    b = rng.standard_normal(nb) * 10.0 ** rng.uniform(-3, 3, nb)
    a = np.r_[1.0, 0.9 ** np.arange(1, na + 1) * rng.uniform(-0.2, 0.2, na)]
    if na == 4:
        b, a = signal.butter(4, 20.0, fs=4096.0)
    x = rng.standard_normal(3000) * 10.0 ** rng.uniform(-2, 2, 3000)
    multi = MultiChannelFilter(b, a, n_channels=1)
    want = np.array([multi.step(np.array([v]))[0] for v in x])
    got = CausalFilter(b, a).apply(x)
    assert np.array_equal(got, want)


def test_filter_rejects_bad_coefficients():
    with pytest.raises(ValueError):
        CausalFilter([])
    with pytest.raises(ValueError):
        CausalFilter([1.0, np.nan])
    with pytest.raises(ValueError):
        CausalFilter([1.0], [0.0, 1.0])


def test_params_roundtrip_and_float_format(tmp_path):
    path = tmp_path / 'compensator.yaml'
    write_compensator_params(path, [1, 2, 3], [1, -0.5], 1024, 'wls',
                             {'plant': 'plant.yaml', 'n_taps': 3, 'fc_hz': 64.0})
    text = path.read_text()
    doc = yaml.safe_load(text)
    taps_line = [ln for ln in text.splitlines() if ln.strip().startswith('taps:')][0]
    assert all(('.' in v or 'e' in v) for v in taps_line.split('[')[1].rstrip(']').split(','))
    params = doc['compensator']['ros__parameters']
    assert params['scheme'] == 'wls' and params['provenance']['n_taps'] == 3
    assert set(params) == {'scheme', 'fs_hz', 'taps', 'denominator', 'provenance'}
    loaded = load_compensator_params(path)
    assert loaded['taps'] == [1.0, 2.0, 3.0] and loaded['denominator'] == [1.0, -0.5]
    assert 'created' in loaded['provenance']


def test_params_old_flat_provenance_is_read_and_refused_by_the_node_check(tmp_path):
    """A file of an older 'rths design' (provenance beside the filter fields)."""
    from rths_compensator.params import check_compensator_params

    path = tmp_path / 'old.yaml'
    old = {'scheme': 'wls', 'fs_hz': 1024.0, 'taps': [1.0, 0.5], 'denominator': [1.0],
           'plant': 'plant.yaml', 'n_taps': 2, 'solver': 'lsi', 'created': '2026-11-21'}
    path.write_text(yaml.safe_dump({'compensator': {'ros__parameters': old}}))
    loaded = load_compensator_params(path)
    assert loaded['provenance'] == {'plant': 'plant.yaml', 'n_taps': 2, 'solver': 'lsi',
                                    'created': '2026-11-21'}
    assert loaded['taps'] == [1.0, 0.5]
    with pytest.raises(ValueError, match=r"created, n_taps, plant, solver.*under 'provenance:'"):
        check_compensator_params(old, str(path))
    new = {k: old[k] for k in ('scheme', 'fs_hz', 'taps', 'denominator')}
    check_compensator_params(dict(new, provenance={'plant': 'plant.yaml'}), str(path))
    check_compensator_params(dict(new, **{'provenance.plant': 'plant.yaml'}), 'node')


@pytest.mark.parametrize('taps, den, fs, scheme, field', [
    ([], [1.0], 1024, 'ls', 'taps'), ([np.inf], [1.0], 1024, 'ls', 'taps'),
    ([1.0], [1.0, -1.5], 1024, 'ls', 'unstable'), ([1.0], [0.0], 1024, 'ls', 'a0'),
    ([1.0], [1.0], 0.0, 'ls', 'fs_hz'), ([1.0], [1.0], 1024, 'magic', 'scheme')])
def test_params_write_refuses_invalid(tmp_path, taps, den, fs, scheme, field):
    path = tmp_path / 'c.yaml'
    with pytest.raises(ValueError, match=field):
        write_compensator_params(path, taps, den, fs, scheme, {})
    assert not path.exists()


def test_params_load_errors_name_the_problem(tmp_path):
    with pytest.raises(OSError):
        load_compensator_params(tmp_path / 'missing.yaml')
    bad = tmp_path / 'bad.yaml'
    bad.write_text('other: {}\n')
    with pytest.raises(ValueError, match='compensator'):
        load_compensator_params(bad)
    bad.write_text('compensator:\n  ros__parameters:\n    scheme: ls\n    fs_hz: 1024.0\n')
    with pytest.raises(ValueError, match='taps'):
        load_compensator_params(bad)


def test_identity_params_is_unit_filter():
    p = identity_params(512.0)
    assert p['taps'] == [1.0] and p['fs_hz'] == 512.0
    filt = CausalFilter(p['taps'], p['denominator'])
    assert filt.step(0.25) == 0.25


def test_node_filter_from_yaml_equals_offline_filter(tmp_path):
    """The node path (load YAML -> CausalFilter.step) equals the offline lfilter design."""
    rng = np.random.default_rng(5)
    taps, den = rng.standard_normal(120) * 1e-2, [1.0, -0.3]
    path = tmp_path / 'comp.yaml'
    write_compensator_params(path, taps, den, 1024.0, 'ls', {'n_taps': 120})
    params = load_compensator_params(path)
    filt = MultiChannelFilter(params['taps'], params['denominator'], 1)
    x = rng.standard_normal(2000)
    out = np.array([filt.step(np.array([v]))[0] for v in x])
    np.testing.assert_allclose(out, signal.lfilter(taps, den, x), rtol=0, atol=1e-13)
