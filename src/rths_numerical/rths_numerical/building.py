"""The seed's two-story RC building (section 6.2): 3-D frame, 40 nodes / 240 DOF, condensed to 16.

Geometry (seed 6.2): 2 stories of 3.6 m; 2 spans of 2.85 m in x, 1 span of
4.7 m in y; 6 column lines fixed at the ground; E = 26 672 MPa; beams 30 x 50 cm
(width x depth), columns 30 x 30 cm; every beam in 3 elements, every column in
1 element.  Nodes: 12 beam-column joints + 14 beams x 2 inner nodes = 40 free
nodes, 6 DOF each = 240 DOF (ground nodes are fixed and not counted).

Elements: Euler-Bernoulli 3-D frame elements (axial EA/L, torsion GJ/L with
G = E / (2 (1 + 0.2)) and the rectangle torsion constant, bending 12EI/L^3
blocks) and consistent mass matrices (mL/420 bending blocks, mL/6 axial,
rotary inertia m (Iy + Iz) / A in torsion).

Mass: the seed gives no floor masses.  The building mass is taken from the
stated ratio 5 DTM / building = 2.06 % with the DTM moving mass of Table 4
(258.35 kg): ``m_b = 5 * 258.35 / 0.0206 = 62 706 kg``, half on each floor,
spread as a uniform line mass over that floor's beams (slab, finishes and
frame mass together).

16-DOF model (seed: "rigid diaphragm for each floor and neglecting all
rotational DOFs and all vertical DOFs except ... at the intercepts of the
column and beam elements"): (1) rigid-diaphragm constraint, in-plane
translations of every floor node follow the floor's (Ux, Uy, Theta);
(2) Guyan (static) condensation of K and M onto the masters Ux, Uy of each
floor + the vertical DOF of the 12 joints = 2 x 2 + 12 = 16 DOF.  The
diaphragm rotations, all node rotations and the inner beam nodes' vertical
DOFs are condensed out.

240-DOF model: the same frame with the same rigid diaphragms (1), imposed as a
penalty stiffness so that all 240 DOFs stay (``building_240dof``; the bare frame,
whose floors flex in plane, is ``building_240dof(diaphragms=False)``).  The two
models then differ only by the Guyan condensation (2), which neglects the inertia of
the condensed DOFs in their own dynamics: seed figure 33 (same 2nd-floor response).

Damping (seed 6.2): Rayleigh ``C = a0 M + a1 K`` with 4.2 % and 10 % on the
first two x-direction modes (identified by effective modal mass in x).
DOF order of the 16-DOF model: ``[Ux1, Uy1, Ux2, Uy2, uz joints floor 1 (6),
uz joints floor 2 (6)]``; the interface DOF is Ux2 (index 2), also the output.
"""

from functools import lru_cache
from itertools import pairwise
import math

import numpy as np

from .dtm import SEED_CONFIGURATION, TABLE4
from .model import LinearModel, rayleigh_coefficients

E_PA = 26672e6
NU = 0.2
STORY_H = 3.6
SPAN_X = 2.85
SPAN_Y = 4.7
BEAM_BD = (0.30, 0.50)   # width, depth [m]
COL_BD = (0.30, 0.30)
N_DTM = 5
MASS_RATIO = 0.0206
BUILDING_MASS_KG = N_DTM * TABLE4[SEED_CONFIGURATION].m_d / MASS_RATIO
ZETA_MODES = (0.042, 0.10)
SEED_FREQS_HZ = (2.81, 7.77)
IX2 = 2  # index of the 2nd-floor x DOF in the 16-DOF model
# rigid-diaphragm penalty of the 240-DOF model, x the frame's largest in-plane diagonal
# stiffness (8.5e9 N/m): 1e3 converges the x frequencies to 5e-7 of their alpha -> inf
# limit at cond(K) = 2.1e7 (1e2: 5e-6 at 2.2e6; 1e5: no gain at 2.1e9).
DIAPHRAGM_PENALTY = 1e3


def _torsion_constant(b, d):
    a, c = max(b, d), min(b, d)
    return a * c ** 3 * (1 / 3 - 0.21 * (c / a) * (1 - c ** 4 / (12 * a ** 4)))


def _frame_element(xi, xj, section, line_mass, ref):
    """Global 12x12 stiffness and consistent mass of a 3-D frame element."""
    b, d = section
    A = b * d
    Iz = b * d ** 3 / 12  # bending in the plane of local y (ref direction)
    Iy = d * b ** 3 / 12
    J = _torsion_constant(b, d)
    G = E_PA / (2 * (1 + NU))
    dx = np.asarray(xj, float) - np.asarray(xi, float)
    L = float(np.linalg.norm(dx))
    ex = dx / L
    ey = np.asarray(ref, float) - np.dot(ref, ex) * ex
    ey /= np.linalg.norm(ey)
    ez = np.cross(ex, ey)
    lam = np.vstack([ex, ey, ez])
    k = np.zeros((12, 12))
    ea = E_PA * A / L
    gj = G * J / L
    k[np.ix_([0, 6], [0, 6])] = ea * np.array([[1, -1], [-1, 1]])
    k[np.ix_([3, 9], [3, 9])] = gj * np.array([[1, -1], [-1, 1]])
    # v, theta_z (local x-y plane, inertia Iz)
    kv = E_PA * Iz / L ** 3 * np.array([[12, 6 * L, -12, 6 * L],
                                        [6 * L, 4 * L * L, -6 * L, 2 * L * L],
                                        [-12, -6 * L, 12, -6 * L],
                                        [6 * L, 2 * L * L, -6 * L, 4 * L * L]])
    kw = E_PA * Iy / L ** 3 * np.array([[12, -6 * L, -12, -6 * L],
                                        [-6 * L, 4 * L * L, 6 * L, 2 * L * L],
                                        [-12, 6 * L, 12, 6 * L],
                                        [-6 * L, 2 * L * L, 6 * L, 4 * L * L]])
    iv = [1, 5, 7, 11]
    iw = [2, 4, 8, 10]
    k[np.ix_(iv, iv)] = kv
    k[np.ix_(iw, iw)] = kw
    m = np.zeros((12, 12))
    if line_mass > 0:
        mt = line_mass * L
        m[np.ix_([0, 6], [0, 6])] = mt / 6 * np.array([[2, 1], [1, 2]])
        rot = line_mass * (Iy + Iz) / A * L
        m[np.ix_([3, 9], [3, 9])] = rot / 6 * np.array([[2, 1], [1, 2]])
        mv = mt / 420 * np.array([[156, 22 * L, 54, -13 * L],
                                  [22 * L, 4 * L * L, 13 * L, -3 * L * L],
                                  [54, 13 * L, 156, -22 * L],
                                  [-13 * L, -3 * L * L, -22 * L, 4 * L * L]])
        mw = mt / 420 * np.array([[156, -22 * L, 54, 13 * L],
                                  [-22 * L, 4 * L * L, -13 * L, -3 * L * L],
                                  [54, -13 * L, 156, 22 * L],
                                  [13 * L, -3 * L * L, 22 * L, 4 * L * L]])
        m[np.ix_(iv, iv)] = mv
        m[np.ix_(iw, iw)] = mw
    T = np.kron(np.eye(4), lam)
    return T.T @ k @ T, T.T @ m @ T


@lru_cache(maxsize=4)
def _frame(building_mass_kg):
    """Assemble the 240-DOF matrices; return (K, M, coords, joint_ids, floor_of_node)."""
    xs = [0.0, SPAN_X, 2 * SPAN_X]
    ys = [0.0, SPAN_Y]
    coords = []   # free nodes
    index = {}

    def node(p):
        key = tuple(round(c, 6) for c in p)
        if key not in index:
            index[key] = len(coords)
            coords.append(key)
        return index[key]

    elems = []
    joints = []
    for floor in (1, 2):
        z = floor * STORY_H
        for y in ys:
            for x in xs:
                joints.append(node((x, y, z)))
    beams = []
    for floor in (1, 2):
        z = floor * STORY_H
        for y in ys:
            for x0, x1 in pairwise(xs):
                beams.append(((x0, y, z), (x1, y, z)))
        for x in xs:
            beams.append(((x, ys[0], z), (x, ys[1], z)))
    beam_len = {1: 0.0, 2: 0.0}
    for p0, p1 in beams:
        beam_len[int(round(p0[2] / STORY_H))] += math.dist(p0, p1)
    for p0, p1 in beams:
        floor = int(round(p0[2] / STORY_H))
        pts = [tuple(np.asarray(p0) + (np.asarray(p1) - np.asarray(p0)) * s)
               for s in (0, 1 / 3, 2 / 3, 1)]
        ids = [node(p) for p in pts]
        lm = building_mass_kg / 2 / beam_len[floor]
        for a, b in pairwise(ids):
            elems.append((a, b, BEAM_BD, lm, (0.0, 0.0, 1.0)))
    for y in ys:
        for x in xs:
            top1, top2 = index[(x, y, STORY_H)], index[(x, y, round(2 * STORY_H, 6))]
            elems.append((None, top1, COL_BD, 0.0, (1.0, 0.0, 0.0), (x, y, 0.0)))
            elems.append((top1, top2, COL_BD, 0.0, (1.0, 0.0, 0.0)))
    n = 6 * len(coords)
    K = np.zeros((n, n))
    M = np.zeros((n, n))
    for e in elems:
        a, b, sec, lm, ref = e[:5]
        pa = e[5] if a is None else coords[a]
        ke, me = _frame_element(pa, coords[b], sec, lm, ref)
        dofs = ([] if a is None else list(range(6 * a, 6 * a + 6))) + list(range(6 * b, 6 * b + 6))
        sel = slice(6, 12) if a is None else slice(0, 12)
        K[np.ix_(dofs, dofs)] += ke[sel, sel]
        M[np.ix_(dofs, dofs)] += me[sel, sel]
    floor_of = [int(round(c[2] / STORY_H)) for c in coords]
    return K, M, np.array(coords), joints, floor_of


def _in_plane_map(coords, floor_of):
    """Return the rigid-diaphragm map ``T1`` (u_240 = T1 q).

    Rigid-diaphragm map ``T1``: u_240 = T1 q, q = [Ux1, Uy1, Th1, Ux2, Uy2, Th2, per node
    (uz, rx, ry, rz)].  The in-plane translations of a floor node follow its floor's
    (Ux, Uy, Theta) about the plan centre; every other DOF is its own coordinate.
    """
    nn = len(coords)
    centre = np.array([SPAN_X, SPAN_Y / 2])
    T1 = np.zeros((6 * nn, 6 + 4 * nn))
    for i, (x, y, _) in enumerate(coords):
        f = floor_of[i] - 1
        T1[6 * i, 3 * f] = 1.0
        T1[6 * i, 3 * f + 2] = -(y - centre[1])
        T1[6 * i + 1, 3 * f + 1] = 1.0
        T1[6 * i + 1, 3 * f + 2] = x - centre[0]
        for j in range(4):
            T1[6 * i + 2 + j, 6 + 4 * i + j] = 1.0
    return T1


def _condensation(building_mass_kg):
    """Return the 240 -> 16 transformation T (u_240 = T q_16) and the K, M of the frame."""
    K, M, coords, joints, floor_of = _frame(building_mass_kg)
    T1 = _in_plane_map(coords, floor_of)
    nq = T1.shape[1]
    masters = [0, 1, 3, 4] + [6 + 4 * j for j in joints]
    slaves = [i for i in range(nq) if i not in masters]
    K1 = T1.T @ K @ T1
    kss = K1[np.ix_(slaves, slaves)]
    ksm = K1[np.ix_(slaves, masters)]
    T2 = np.zeros((nq, len(masters)))
    T2[masters, np.arange(len(masters))] = 1.0
    T2[slaves, :] = -np.linalg.solve(kss, ksm)
    return T1 @ T2, K, M, coords, floor_of


@lru_cache(maxsize=4)
def _diaphragm_penalty(building_mass_kg):
    """Penalty stiffness of the rigid floor diaphragms on the 240 DOF; return (K_pen, alpha).

    For each floor, ``v`` (the u_x, u_y of the floor's 20 nodes) must lie in the span of
    the rows of the condensation's own map ``T1`` for that floor (rigid in-plane motion
    Ux, Uy, Theta).  With ``Q`` an orthonormal basis of that 3-D span, the penalty energy
    is ``alpha / 2 |(I - Q Q^T) v|^2``, so ``K_pen = alpha (I - Q Q^T)``: symmetric,
    positive semi-definite, zero on rigid floor motions, and no extra DOFs.
    ``alpha = DIAPHRAGM_PENALTY`` x the largest in-plane diagonal entry of the frame's K.
    """
    K, _, coords, _, floor_of = _frame(building_mass_kg)
    T1 = _in_plane_map(coords, floor_of)
    in_plane = np.sort(np.r_[0:K.shape[0]:6, 1:K.shape[0]:6])
    alpha = DIAPHRAGM_PENALTY * float(np.max(np.diag(K)[in_plane]))
    K_pen = np.zeros_like(K)
    for f in (1, 2):
        dofs = [d for d in in_plane if floor_of[d // 6] == f]
        Q, _ = np.linalg.qr(T1[np.ix_(dofs, [3 * f - 3, 3 * f - 2, 3 * f - 1])])
        K_pen[np.ix_(dofs, dofs)] = alpha * (np.eye(len(dofs)) - Q @ Q.T)
    return K_pen, alpha


def _damped(M, K, gamma, names, interface, output, name, freqs=None):
    model = LinearModel(M, np.zeros_like(M), K, gamma, interface, output, name, names)
    if freqs is None:
        freqs, _ = model.dominant_frequencies(2)
    a0, a1 = rayleigh_coefficients(freqs[0], freqs[1], *ZETA_MODES)
    model.C = a0 * M + a1 * K
    return model


@lru_cache(maxsize=4)
def _building16(building_mass_kg):
    T, K, M, coords, floor_of = _condensation(building_mass_kg)
    Kr = T.T @ K @ T
    Mr = T.T @ M @ T
    Kr = 0.5 * (Kr + Kr.T)
    Mr = 0.5 * (Mr + Mr.T)
    gamma = np.zeros(16)
    gamma[[0, 2]] = 1.0
    names = ['Ux1', 'Uy1', 'Ux2', 'Uy2'] + [f'uz_j{f}_{i}' for f in (1, 2) for i in range(6)]
    return Mr, Kr, gamma, names


def building_16dof(building_mass_kg=BUILDING_MASS_KG):
    """Return the condensed 16-DOF building (interface/output DOF: Ux2, index 2)."""
    Mr, Kr, gamma, names = _building16(float(building_mass_kg))
    return _damped(Mr.copy(), Kr.copy(), gamma, names, [IX2], IX2, 'building2story-16dof')


def building_240dof(building_mass_kg=BUILDING_MASS_KG, diaphragms=True):
    """Return the 240-DOF frame; output DOF: ux of the middle 2nd-floor joint at y = 0.

    ``diaphragms=True`` (default) adds the rigid floor diaphragms the 16-DOF
    condensation assumes (the in-plane u_x, u_y of each floor's nodes follow one rigid
    (Ux, Uy, Theta) motion) as a penalty stiffness (``_diaphragm_penalty``), keeping all
    240 DOFs; ``diaphragms=False`` is the bare frame (its floors flex in plane).
    Damping uses the Rayleigh coefficients of the 16-DOF model's x modes so
    that both models are damped alike.  ``gamma`` is 1 on every node's ux.
    """
    mass = float(building_mass_kg)
    K, M, coords, joints, floor_of = _frame(mass)
    K = K + _diaphragm_penalty(mass)[0] if diaphragms else K.copy()
    gamma = np.zeros(K.shape[0])
    gamma[0::6] = 1.0
    freqs, _ = building_16dof(building_mass_kg).dominant_frequencies(2)
    # middle joint of the y = 0 line on floor 2
    mid = int(np.flatnonzero((np.abs(coords[:, 0] - SPAN_X) < 1e-6) & (coords[:, 1] == 0)
                             & (np.abs(coords[:, 2] - 2 * STORY_H) < 1e-6))[0])
    names = [f'n{i}_{c}' for i in range(len(coords)) for c in ('ux', 'uy', 'uz', 'rx', 'ry', 'rz')]
    name = 'building2story-240dof' + ('' if diaphragms else '-nodiaphragm')
    return _damped(M.copy(), K, gamma, names, [6 * mid], 6 * mid, name, freqs)


def floor2_x_dofs_240(building_mass_kg=BUILDING_MASS_KG):
    """Return the ux indices of the 240-DOF model's 2nd-floor nodes (their mean = the floor)."""
    _, _, coords, _, floor_of = _frame(float(building_mass_kg))
    return [6 * i for i, f in enumerate(floor_of) if f == 2]


def x_frequencies(model=None):
    """First two x-direction natural frequencies [Hz] of the 16-DOF building."""
    model = building_16dof() if model is None else model
    f, _ = model.dominant_frequencies(2)
    return float(f[0]), float(f[1])
