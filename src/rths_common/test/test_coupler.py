"""Tests of the rigid-coupler kinematics (rths_common.coupler)."""

import numpy as np
import pytest

from rths_common.coupler import Coupler

# The maRTHS benchmark's coupler (fcn_coupler_geometry.m of github.com/FermandoisLab/
# maRTHS-bmk-RoDeAC at eb0f21bae8a0dd7100a1620db995b4ff22b70465): attachment points at
# (0.2667, -0.127) m and (0.2667, 0.127) m from the interface node.
MARTHS = Coupler.from_offsets([(0.2667, -0.127), (0.2667, 0.127)])


def test_offsets_give_the_benchmark_arms_and_angles():
    assert MARTHS.d[0] == pytest.approx(np.hypot(0.2667, 0.127))
    assert np.degrees(MARTHS.alpha[1]) == pytest.approx(25.4633, abs=1e-3)
    assert np.degrees(MARTHS.alpha[0]) == pytest.approx(-25.4633, abs=1e-3)


def test_pure_translation_moves_every_actuator_alike():
    s = MARTHS.strokes(0.004, 0.0)
    assert s == pytest.approx([0.004, 0.004])


def test_small_rotation_matches_the_lateral_offsets():
    # theta > 0 (counter-clockwise): the point below the node (y = -0.127) moves +x.
    s = MARTHS.strokes(0.0, 1e-6)
    assert s == pytest.approx([0.127e-6, -0.127e-6], rel=1e-4)
    assert MARTHS.jacobian() == pytest.approx(np.array([[1, 0.127], [1, -0.127]]))


def test_large_rotation_differs_from_the_linear_map_by_the_second_order_term():
    theta = 0.05
    exact = MARTHS.strokes(0.0, theta)
    linear = MARTHS.strokes(0.0, theta, linear=True)
    # d (cos(t + a) - cos a) + d sin(a) t = -d cos(a) t^2 / 2 + O(t^3); d cos a = 0.2667.
    assert exact - linear == pytest.approx([-0.2667 * theta ** 2 / 2] * 2, rel=0.05)


@pytest.mark.parametrize('linear', [False, True])
def test_inverse_recovers_the_dofs_of_arrays(linear):
    rng = np.random.default_rng(3)
    x = rng.uniform(-0.02, 0.02, (4, 5))
    th = rng.uniform(-0.1, 0.1, (4, 5))
    x2, th2 = MARTHS.dofs(MARTHS.strokes(x, th, linear=linear), linear=linear)
    assert x2 == pytest.approx(x, abs=1e-12)
    assert th2 == pytest.approx(th, abs=1e-12)


def test_three_actuators_least_squares_inverse():
    c = Coupler.from_offsets([(0.3, -0.2), (0.3, 0.0), (0.3, 0.25)])
    x2, th2 = c.dofs(c.strokes(np.array([0.01]), np.array([0.03])))
    assert (x2[0], th2[0]) == pytest.approx((0.01, 0.03), abs=1e-12)


@pytest.mark.parametrize('d, alpha, match', [
    ((0.3,), (0.1, 0.2), 'same length'),
    ((0.3, -0.1), (0.1, 0.2), 'arm'),
    ((0.3, 0.3), (0.0, 0.0), 'no independent rotation'),
    ((0.3, float('nan')), (0.0, 0.1), 'finite'),
])
def test_bad_geometry_is_refused(d, alpha, match):
    with pytest.raises(ValueError, match=match):
        Coupler(d, alpha)


def test_wrong_number_of_strokes_is_refused():
    with pytest.raises(ValueError, match='3 strokes given for 2'):
        MARTHS.dofs(np.zeros(3))


def test_interface_forces_do_the_same_work_as_the_actuators():
    # virtual work: F_x dx + M dtheta = sum f_i ds_i for a small motion at any rotation
    f = np.array([1200.0, -300.0])
    for theta in (0.0, 0.08):
        fx, m = MARTHS.interface_forces(f, theta)
        dx, dth = 1e-7, 2e-7
        ds = MARTHS.strokes(dx, theta + dth) - MARTHS.strokes(0.0, theta)
        assert fx * dx + m * dth == pytest.approx(float(f @ ds), rel=1e-5)
    # equal pushes give no moment; opposite pushes only a moment of 2 * 0.127 m * f
    assert MARTHS.interface_forces(np.array([500.0, 500.0])) == pytest.approx((1000.0, 0.0))
    fx, m = MARTHS.interface_forces(np.array([500.0, -500.0]))
    assert (fx, m) == pytest.approx((0.0, 2 * 0.127 * 500.0))


def test_wrong_number_of_forces_is_refused():
    with pytest.raises(ValueError, match='1 forces given for 2'):
        MARTHS.interface_forces(np.zeros(1))
