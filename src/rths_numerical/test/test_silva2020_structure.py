"""The benchmark's 3-story structure and numerical substructures (Silva et al. 2020)."""

import numpy as np
import pytest

from rths_numerical import silva2020
from rths_numerical.substructure import build_model


@pytest.mark.parametrize('case', [1, 2, 3, 4])
def test_cases_follow_table_1(case):
    mass, zeta = silva2020.CASES[case]
    ref = silva2020.reference_model(case)
    assert np.allclose(np.diag(ref.M), mass)
    w2, phi = np.linalg.eig(np.linalg.solve(ref.M, ref.K))
    phi = phi / np.sqrt(np.einsum('ij,ik,kj->j', phi, ref.M, phi))
    modal_c = phi.T @ ref.C @ phi
    assert np.allclose(np.diag(modal_c) / (2 * np.sqrt(w2.real)), zeta, rtol=1e-9)


def test_numerical_substructure_is_reference_minus_specimen():
    ref = silva2020.reference_model(3)
    num = silva2020.numerical_model(3, k_e=1.2e6)
    spec = np.zeros((3, 3))
    spec[0, 0] = 1.0
    assert np.allclose(ref.M - num.M, 29.13 * spec)
    assert np.allclose(ref.K - num.K, 1.2e6 * spec)
    c_e = 2 * 0.0097 * np.sqrt(1.2e6 * 29.13)
    assert np.allclose(ref.C - num.C, c_e * spec)
    # the ground acceleration loads the reference masses: M_n Gamma = M_r 1
    assert np.allclose(num.M @ num.gamma, ref.M @ np.ones(3))


def test_first_frequency_and_built_in_name():
    f1 = np.sqrt(np.min(np.linalg.eigvals(np.linalg.solve(
        silva2020.reference_model(1).M, silva2020.K_REFERENCE)).real)) / (2 * np.pi)
    assert abs(f1 - 3.61) < 0.01      # benchmark reference frame, case 1: 3.61 Hz
    model = build_model({'model': 'silva2020_case4'})
    assert model.n == 3 and model.interface_dofs == [0]
    with pytest.raises(ValueError, match='case'):
        build_model({'model': 'silva2020_case7'})
