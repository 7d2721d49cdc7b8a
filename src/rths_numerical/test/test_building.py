"""The seed's two-story building (section 6.2)."""

import numpy as np
import pytest

from rths_numerical import building as bld
from rths_numerical.ground_motion import baseline_correct, ground_motion
from rths_numerical.reference import integrate_model, relative_rms_error


def test_sizes_and_mass_from_mass_ratio():
    """40 nodes / 240 DOF, condensed to 16 DOF; 5 x 258.35 kg / m_b = 2.06 % (seed 6.2)."""
    full = bld.building_240dof()
    small = bld.building_16dof()
    assert full.n == 240 and small.n == 16
    assert 5 * 258.35 / bld.BUILDING_MASS_KG == pytest.approx(0.0206)
    # Guyan reduction adds the small rotary inertia of the slave rotations
    assert small.gamma @ small.M @ small.gamma == pytest.approx(bld.BUILDING_MASS_KG, rel=1e-3)
    assert full.gamma @ full.M @ full.gamma == pytest.approx(bld.BUILDING_MASS_KG, rel=1e-6)
    assert np.all(np.linalg.eigvalsh(small.M) > 0) and np.all(np.linalg.eigvalsh(full.M) > 0)


def test_x_frequencies_near_seed():
    """X modes vs the seed's 2.81 Hz / 7.77 Hz (the masses are our assumption: within 8 %)."""
    f1, f2 = bld.x_frequencies()
    assert f1 == pytest.approx(bld.SEED_FREQS_HZ[0], rel=0.08)
    assert f2 == pytest.approx(bld.SEED_FREQS_HZ[1], rel=0.08)


def test_240_dof_with_diaphragms_has_the_16_dof_x_frequencies():
    """Seed 6.2: the 16-DOF model is the 240-DOF one with rigid diaphragms, then condensed.

    With the same diaphragms the two differ only by the Guyan condensation, a Ritz
    reduction: its frequencies are upper bounds, and close ones.  The bare frame's floors
    flex in plane, which lowers the 2nd x mode by about 3 %.
    """
    f16 = bld.building_16dof().dominant_frequencies(2)[0]
    f240 = bld.building_240dof().dominant_frequencies(2)[0]
    bare = bld.building_240dof(diaphragms=False).dominant_frequencies(2)[0]
    assert np.all(f16 >= f240)
    assert f240 == pytest.approx(f16, rel=5e-4)
    assert bare[1] < f16[1] * 0.98


def test_diaphragm_penalty_only_resists_non_rigid_floor_motion():
    """The penalty is zero on rigid in-plane floor motions and stiff on any other."""
    full, bare = bld.building_240dof(), bld.building_240dof(diaphragms=False)
    K_pen = full.K - bare.K
    assert np.allclose(K_pen, K_pen.T)
    _, _, coords, _, floor_of = bld._frame(bld.BUILDING_MASS_KG)
    top = np.array(floor_of) == 2
    rigid = np.zeros((240, 3))
    rigid[0::6, 0] = top  # floor 2 translates in x
    rigid[1::6, 1] = top  # ... in y
    rigid[0::6, 2] = -coords[:, 1] * top  # ... turns about the vertical axis through x = y = 0
    rigid[1::6, 2] = coords[:, 0] * top
    scale = np.max(np.abs(K_pen))
    assert np.max(np.abs(K_pen @ rigid)) < 1e-9 * scale
    stretch = np.zeros(240)
    stretch[0::6] = coords[:, 0] * top  # floor 2 stretched in x: not rigid
    assert stretch @ K_pen @ stretch > 1e3 * stretch @ bare.K @ stretch
    assert np.all(np.linalg.eigvalsh(K_pen) > -1e-9 * scale)


def test_rayleigh_damping_on_x_modes():
    """4.2 % and 10 % on the two x-direction modes (seed 6.2)."""
    b = bld.building_16dof()
    f, phi = b.modes()
    _, idx = b.dominant_frequencies(2)
    zeta = np.diag(phi.T @ b.C @ phi) / (2 * 2 * np.pi * f)
    assert zeta[idx] == pytest.approx(bld.ZETA_MODES, rel=1e-6)


def test_16_and_240_dof_same_2nd_floor_response():
    """Seed figure 33: the condensed and the full model give the same 2nd-floor response."""
    fs = 256.0
    ag, _, _ = baseline_correct(ground_motion('kobe', fs, 0.135, 12.0), 1 / fs)
    d16, _ = integrate_model(bld.building_16dof(), ag, 1 / fs)
    u16 = d16[:, bld.IX2]
    floor2 = bld.floor2_x_dofs_240()
    d240, _ = integrate_model(bld.building_240dof(), ag, 1 / fs)
    # the diaphragm holds: every 2nd-floor node moves alike in x
    spread = np.max(np.ptp(d240[:, floor2], axis=1))
    assert spread < 1e-4 * np.max(np.abs(u16))
    u240 = d240[:, floor2].mean(axis=1)
    # only the Guyan condensation separates them (about 0.02 %)
    assert relative_rms_error(u240, u16) < 0.1
    assert np.max(np.abs(u240)) == pytest.approx(np.max(np.abs(u16)), rel=1e-3)
    # the bare frame (no diaphragm) is only "similar" (several % apart)
    bare, _ = integrate_model(bld.building_240dof(diaphragms=False), ag, 1 / fs)
    assert relative_rms_error(bare[:, floor2].mean(axis=1), u16) > 1.0
