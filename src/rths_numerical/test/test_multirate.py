"""The substructure at a divisor of the loop rate (rths_numerical.multirate, ``rate_divisor``)."""

import numpy as np
import pytest

from rths_numerical.multirate import MultiRateSubstructure
from rths_numerical.reference import DTMSpecimen, coupled_rths, relative_rms_error
from rths_numerical.substructure import NumericalSubstructure, make_substructure

#: The seed's 16-DOF building at the RTHS benchmark's rate (Kobe x 0.135, as test_substructure).
BUILDING = {'model': 'building2story', 'record': 'kobe', 'scale': 0.135, 'duration_s': 1.0,
            'fs_hz': 4096.0}


def _commands(sub, forces):
    """Run ``sub`` with ``forces[k]`` at loop step k; the command of every step."""
    out = [sub.first_displacement()[0]]
    for f in forces:
        if sub.done():
            break
        out.append(sub.advance(np.array([f]))[0])
    return np.array(out[:sub.n_steps])


def test_a_divisor_of_1_is_the_plain_substructure_and_4_keeps_the_loop_s_sizes():
    plain = make_substructure(BUILDING)
    assert type(plain) is NumericalSubstructure
    assert type(make_substructure(dict(BUILDING, rate_divisor=1))) is NumericalSubstructure
    sub = make_substructure(dict(BUILDING, rate_divisor=4))
    assert isinstance(sub, MultiRateSubstructure)
    assert sub.n_steps == plain.n_steps == 4096 and sub.dt == pytest.approx(1 / 4096)
    assert sub.inner.n_steps == 1024 and sub.inner.dt == pytest.approx(1 / 1024)
    assert sub.model is sub.inner.model and sub.iface == plain.iface
    assert (sub.frame, sub.force_scale) == (plain.frame, plain.force_scale)
    # the numerical substructure takes every 4th sample of the loop-rate record
    np.testing.assert_array_equal(sub.inner.ag, plain.ag[::4])
    np.testing.assert_array_equal(sub.ag, plain.ag)


def test_the_numerical_steps_are_the_inner_run_and_the_loop_steps_lie_on_its_parabola():
    """Knots: the inner substructure run alone with every 4th force; between them the parabola.

    The forces between the knots do not enter the integration (module doc).
    """
    n = 4
    sub = make_substructure(dict(BUILDING, rate_divisor=n))
    rng = np.random.default_rng(3)
    forces = rng.normal(0.0, 500.0, sub.n_steps)
    cmd = _commands(sub, forces)
    inner = make_substructure(dict(BUILDING, rate_divisor=n)).inner
    x = np.array([inner.first_displacement()[0]]
                 + [inner.advance(np.array([f]))[0] for f in forces[::n]])
    np.testing.assert_array_equal(cmd[::n], x[:len(cmd[::n])])
    m = 10                                   # loop steps 41..43 lie between knots 10 and 11
    for j in range(1, n):
        s = j / n
        on = x[m] + s * (x[m + 1] - x[m - 1]) / 2 + s * s * ((x[m + 1] + x[m - 1]) / 2 - x[m])
        assert cmd[m * n + j] == pytest.approx(on, rel=1e-12, abs=1e-18)
    other = forces.copy()
    other[np.arange(sub.n_steps) % n != 0] += 1e4          # forces between the knots only
    sub.reset()
    np.testing.assert_array_equal(_commands(sub, other), cmd)


def test_rths_with_a_dtm_at_a_quarter_rate_stays_within_0_1_percent_of_the_single_rate_run():
    """The seed's building with the valve #4 DTM at 4096 Hz, 4 s of Kobe x 0.135.

    Measured on 2026-11-29: 0.040 % RMS on the roof displacement at N = 4 (the
    piecewise-linear target it replaced: 3.0 %).
    """
    params = dict(BUILDING, duration_s=4.0)
    single = make_substructure(params)
    ref = coupled_rths(single, DTMSpecimen('valve4', single.dt))
    sub = make_substructure(dict(params, rate_divisor=4))
    out = coupled_rths(sub, DTMSpecimen('valve4', sub.dt))
    for key in ('time', 'output_disp', 'command', 'measured_force', 'ground_accel',
                'displacements', 'interface_disp', 'output_accel_abs'):
        assert len(out[key]) == len(ref[key]) == sub.n_steps, key
    np.testing.assert_array_equal(out['ground_accel'], ref['ground_accel'])
    assert relative_rms_error(out['output_disp'], ref['output_disp']) < 0.1
    assert relative_rms_error(out['command'], ref['command']) < 0.1
    first = out['output_disp'].copy()
    sub.reset()
    assert sub.state()['step'] == 0
    again = coupled_rths(sub, DTMSpecimen('valve4', sub.dt))
    np.testing.assert_array_equal(again['output_disp'], first)
    assert sub.state()['step'] == sub.n_steps
    assert sub.state()['output_disp'] == again['output_disp'][-1]
    with pytest.raises(RuntimeError):
        sub.advance(np.zeros(1))


def test_the_blwn_band_is_read_only_for_a_blwn_record():
    """Another record's run ignores blwn_band_hz, with or without a divisor."""
    for n in (1, 4):
        sub = make_substructure(dict(BUILDING, duration_s=0.1, rate_divisor=n,
                                     blwn_band_hz='unused'))
        assert sub.n_steps == 410


def test_a_record_length_that_is_not_a_multiple_of_the_divisor_runs_every_loop_step():
    params = dict(BUILDING, duration_s=1001 / 4096)
    plain = make_substructure(params)
    sub = make_substructure(dict(params, rate_divisor=4))
    assert sub.n_steps == plain.n_steps == 1001 and sub.inner.n_steps == 251
    cmd = _commands(sub, np.zeros(sub.n_steps))
    assert sub.done() and len(cmd) == 1001 and np.all(np.isfinite(cmd))
    assert len(sub.history()['displacements']) == 1001


@pytest.mark.parametrize('params, words', [
    ({'rate_divisor': 0}, 'rate_divisor = 0: give a whole number in 1..64'),
    ({'rate_divisor': 2.5}, 'rate_divisor = 2.5'),
    ({'rate_divisor': 65}, '1..64'),
    ({'rate_divisor': True}, 'rate_divisor = True'),
    ({'rate_divisor': 'four'}, "rate_divisor = 'four'"),
    ({'rate_divisor': {'n': 4}}, "rate_divisor = {'n': 4}: give a whole number"),
    ({'rate_divisor': float('nan')}, 'rate_divisor = nan'),
    ({'record': 'blwn', 'blwn_band_hz': 600.0, 'rate_divisor': 4},
     'does not sample the blwn excitation (600 Hz; its Nyquist frequency is 512 Hz)'),
    ({'model': 'marths', 'record': 'kobe', 'rate_divisor': 4}, "model 'marths' runs at the loop"),
])
def test_a_bad_divisor_is_refused_naming_the_parameter(params, words):
    with pytest.raises(ValueError, match='parameter rate_divisor') as err:
        make_substructure(dict(BUILDING, **params))
    assert words in str(err.value)
