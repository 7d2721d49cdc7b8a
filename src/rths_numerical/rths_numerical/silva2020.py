"""Reference structure and numerical substructures of the RTHS benchmark (Silva et al. 2020).

The reference structure is a 3-story shear frame with the condensed stiffness matrix
:data:`K_REFERENCE` of the benchmark's building cases, equal floor masses and the same
modal damping ratio in every mode (:data:`CASES`, Table 1 of the paper).  The physical
specimen (``m_e``, ``c_e``, ``k_e``; :mod:`rths_actuator_bridge.silva2020`) is part of
floor 1; the numerical substructure is the reference minus the specimen (paper eq. 4)::

    M_n = M_r - M_e,  C_n = C_r - C_e,  K_n = K_r - K_e

and is loaded by the ground acceleration through the reference masses
(``-M_r 1 a_g``: the benchmark's measured force is the specimen's restoring force in
relative coordinates), i.e. the influence vector ``Gamma = M_n^-1 M_r 1``.

Built-in model names for :func:`.substructure.build_model`: ``silva2020_case1`` ..
``silva2020_case4`` (nominal specimen).
"""

import math

import numpy as np

from .model import LinearModel, modal_damping

#: Stiffness matrix [N/m] of the reference 3-story frame (benchmark building cases).
K_REFERENCE = np.array([
    [26054883.87960384, -23133938.8771082, 5937035.46333915],
    [-23133938.8771082, 32560774.18638033, -14419970.77723698],
    [5937035.46333915, -14419970.77723698, 9267275.50622431]])

#: Partitioning cases (paper Table 1): case -> (floor mass [kg], modal damping ratio [-]).
CASES = {1: (1000.0, 0.05), 2: (1100.0, 0.04), 3: (1300.0, 0.03), 4: (1000.0, 0.03)}

#: Nominal specimen (Table 2): mass [kg], stiffness [N/m], damping ratio [-].
SPECIMEN = {'m_e': 29.13, 'k_e': 1.19e6, 'zeta_e': 0.0097}


def _case(case) -> tuple:
    try:
        return CASES[int(case)]
    except (KeyError, ValueError, TypeError):
        raise ValueError(f'benchmark case {case!r} unknown; use 1, 2, 3 or 4') from None


def reference_model(case) -> LinearModel:
    """Return the whole 3-story reference structure of ``case`` (1..4)."""
    mass, zeta = _case(case)
    m = mass * np.eye(3)
    c = modal_damping(m, K_REFERENCE, zeta)
    return LinearModel(M=m, C=c, K=K_REFERENCE.copy(), gamma=np.ones(3), interface_dofs=[0],
                       output_dof=0, name=f'silva2020_reference_case{int(case)}',
                       dof_names=['floor 1', 'floor 2', 'floor 3'])


def numerical_model(case, m_e: float = None, k_e: float = None,
                    zeta_e: float = None) -> LinearModel:
    """Numerical substructure of ``case``: the reference minus the specimen at floor 1."""
    ref = reference_model(case)
    m_e = SPECIMEN['m_e'] if m_e is None else float(m_e)
    k_e = SPECIMEN['k_e'] if k_e is None else float(k_e)
    zeta_e = SPECIMEN['zeta_e'] if zeta_e is None else float(zeta_e)
    c_e = 2.0 * zeta_e * math.sqrt(k_e * m_e)
    m, c, k = ref.M.copy(), ref.C.copy(), ref.K.copy()
    m[0, 0] -= m_e
    c[0, 0] -= c_e
    k[0, 0] -= k_e
    gamma = np.linalg.solve(m, ref.M @ np.ones(3))
    return LinearModel(M=m, C=c, K=k, gamma=gamma, interface_dofs=[0], output_dof=0,
                       name=f'silva2020_case{int(case)}', dof_names=list(ref.dof_names))


def model_by_name(name: str) -> LinearModel:
    """``silva2020_caseN`` -> :func:`numerical_model` (N = 1..4)."""
    return numerical_model(name[len('silva2020_case'):])
