"""Linear MDOF models ``M u'' + C u' + K u = -M Gamma a_g + F`` and their substructure split.

Seed chapter 3 (eq. 16-21): ``u`` is relative to the ground, ``Gamma`` the
influence vector, ``P = -M Gamma a_g + F`` (eq. 21).  DOFs are split into the
numerical ones (N, NB), the interface DOFs I (where the specimen is attached,
eq. 22-25) and the experimental ones (E, EB) that are not modelled here at all:
the specimen's restoring force ``R^E`` enters the interface rows (eq. 23, 25).

A model YAML file (``load_model_yaml``)::

    name: my-frame               # optional
    M: [[m11, m12], [m21, m22]]  # kg  (or 'masses: [m1, m2]' for a diagonal M)
    K: [[...], [...]]            # N/m
    C: [[...], [...]]            # N s/m, or instead:
    damping: {type: rayleigh, zeta: [0.042, 0.10], modes: [0, 1]}     # modes by index
    # damping: {type: rayleigh, zeta: [0.042, 0.10], freqs_hz: [2.81, 7.77]}  (by frequency)
    # damping: {type: modal, zeta: [0.02, 0.02]}   (one ratio per mode, or one for all)
    influence: [1, 1]            # Gamma, default all ones
    external_force: [0, 500]     # F [N] per DOF, constant in time; default none
    # external_force: {1: 500}   (same, as DOF index: N, for large models)
    # (in Python, LinearModel(external_force_time=s) makes it F s(t), s a function of t [s])
    interface_dofs: [1]          # default: last DOF
    output_dof: 1                # DOF reported as "2nd floor", default: last DOF
    dof_names: [floor1, floor2]  # optional
"""

from dataclasses import dataclass, field
import math

import numpy as np
import scipy.linalg as sla

from rths_common import yamlfile


@dataclass
class LinearModel:
    """Mass [kg], damping [N s/m], stiffness [N/m], influence vector and interface DOFs."""

    M: np.ndarray
    C: np.ndarray
    K: np.ndarray
    gamma: np.ndarray
    interface_dofs: list
    output_dof: int
    name: str = 'model'
    dof_names: list = field(default_factory=list)
    #: external force ``F`` [N] per DOF (None: no external force)
    external_force: np.ndarray = None
    #: optional time function ``s(t)`` [-] of time [s]: the force is ``F s(t)`` (None: constant)
    external_force_time: object = None

    def __post_init__(self):
        """Validate shapes and indices."""
        self.M = np.atleast_2d(np.asarray(self.M, dtype=float))
        self.K = np.atleast_2d(np.asarray(self.K, dtype=float))
        self.C = np.atleast_2d(np.asarray(self.C, dtype=float))
        n = self.M.shape[0]
        self.gamma = np.asarray(self.gamma, dtype=float).reshape(-1)
        for label, mat in (('M', self.M), ('K', self.K), ('C', self.C)):
            if mat.shape != (n, n):
                raise ValueError(f'model {self.name}: {label} is {mat.shape}, expected ({n}, {n})')
        if self.gamma.shape != (n,):
            raise ValueError(f'model {self.name}: influence has {self.gamma.size} entries, '
                             f'expected {n}')
        self.interface_dofs = [int(i) for i in self.interface_dofs]
        for i in self.interface_dofs + [self.output_dof]:
            if not 0 <= i < n:
                raise ValueError(f'model {self.name}: DOF index {i} is outside 0..{n - 1}')
        if not self.dof_names:
            self.dof_names = [f'dof{i}' for i in range(n)]
        if self.external_force is None:
            self.external_force = np.zeros(n)
        self.external_force = np.asarray(self.external_force, dtype=float).reshape(-1)
        if self.external_force.shape != (n,) or not np.all(np.isfinite(self.external_force)):
            raise ValueError(f'model {self.name}: external_force must be {n} finite forces [N], '
                             f'got {self.external_force.size} entries')
        if self.external_force_time is not None and not callable(self.external_force_time):
            raise ValueError(f'model {self.name}: external_force_time must be a function of '
                             'time [s] (or None for a constant force)')

    @property
    def n(self) -> int:
        """Return the number of DOFs."""
        return self.M.shape[0]

    @property
    def has_external_force(self) -> bool:
        """Return True if any entry of the external force is non-zero."""
        return bool(np.any(self.external_force))

    def external_force_scale(self, t):
        """Factor ``s(t)`` [-] of the external force at time(s) ``t`` [s] (1 if constant)."""
        t = np.asarray(t, dtype=float)
        if self.external_force_time is None:
            return np.ones_like(t)
        scale = np.asarray([float(self.external_force_time(x)) for x in t.reshape(-1)])
        if not np.all(np.isfinite(scale)):
            raise ValueError(f'model {self.name}: external_force_time returned nan/inf; '
                             'make it finite over the whole run')
        return scale.reshape(t.shape)

    def load(self, ground_accel, t=0.0):
        """Load vector ``P = -M Gamma a_g + F s(t)`` [N] (seed eq. 21) at one time ``t`` [s]."""
        p = -(self.M @ self.gamma) * float(ground_accel)
        if self.has_external_force:
            p = p + self.external_force * float(self.external_force_scale(t))
        return p

    def modes(self):
        """Return natural frequencies [Hz] (ascending) and mass-normalised mode shapes (columns)."""
        w2, phi = sla.eigh(self.K, self.M)
        return np.sqrt(np.clip(w2, 0.0, None)) / (2 * math.pi), phi

    def effective_mass(self, direction=None):
        """Return the effective modal mass fraction of every mode for influence ``direction``."""
        g = self.gamma if direction is None else np.asarray(direction, dtype=float)
        _, phi = self.modes()
        part = phi.T @ self.M @ g
        return part ** 2 / (g @ self.M @ g)

    def dominant_frequencies(self, count=2, direction=None):
        """Frequencies [Hz] of the ``count`` modes with most effective mass, ascending."""
        f, _ = self.modes()
        eff = self.effective_mass(direction)
        idx = np.sort(np.argsort(eff)[::-1][:count])
        return f[idx], idx

    def with_added(self, dof, mass=0.0, stiffness=0.0, damping=0.0):
        """Return a copy with lumped mass/spring/dashpot (to ground) added at ``dof``."""
        M, C, K = self.M.copy(), self.C.copy(), self.K.copy()
        M[dof, dof] += mass
        C[dof, dof] += damping
        K[dof, dof] += stiffness
        return LinearModel(M, C, K, self.gamma.copy(), list(self.interface_dofs),
                           self.output_dof, self.name, list(self.dof_names),
                           self.external_force.copy(), self.external_force_time)


def rayleigh_coefficients(f1_hz, f2_hz, zeta1, zeta2):
    """Return ``(a0, a1)`` with ``C = a0 M + a1 K`` giving ``zeta1``, ``zeta2`` at two frequencies.

    ``zeta_i = a0 / (2 w_i) + a1 w_i / 2``.
    """
    w1, w2 = 2 * math.pi * f1_hz, 2 * math.pi * f2_hz
    A = np.array([[1 / (2 * w1), w1 / 2], [1 / (2 * w2), w2 / 2]])
    a0, a1 = np.linalg.solve(A, [zeta1, zeta2])
    return float(a0), float(a1)


def modal_damping(M, K, zetas):
    """Return ``C = M Phi diag(2 zeta_i w_i) Phi^T M`` (mass-normalised modes)."""
    w2, phi = sla.eigh(K, M)
    w = np.sqrt(np.clip(w2, 0.0, None))
    z = np.broadcast_to(np.asarray(zetas, dtype=float), w.shape)
    mp = M @ phi
    return mp @ np.diag(2 * z * w) @ mp.T


def sdof_model(mass_kg, freq_hz, zeta):
    """Return a single-DOF model; the DOF is both interface and output."""
    for key, val in (('sdof_mass_kg', mass_kg), ('sdof_freq_hz', freq_hz)):
        if not val > 0:
            raise ValueError(f'{key} = {val} must be positive')
    if not 0 <= zeta < 1:
        raise ValueError(f'sdof_zeta = {zeta} must lie in [0, 1)')
    w = 2 * math.pi * freq_hz
    return LinearModel([[mass_kg]], [[2 * zeta * mass_kg * w]], [[mass_kg * w * w]], [1.0],
                       [0], 0, name='sdof', dof_names=['mass'])


#: Keys of a model YAML file (module docstring).
MODEL_KEYS = ('name', 'M', 'masses', 'K', 'C', 'damping', 'influence', 'external_force',
              'interface_dofs', 'output_dof', 'dof_names')
#: Keys of the ``damping`` mapping.
DAMPING_KEYS = ('type', 'zeta', 'modes', 'freqs_hz')


def _matrix(data, key, source, unit):
    """``data[key]`` as a finite float matrix (ValueError naming file, field and fix)."""
    try:
        mat = np.atleast_2d(np.asarray(data[key], dtype=float))
    except (TypeError, ValueError):
        raise ValueError(f'{source}: field {key} must be a matrix of numbers in {unit} (a list '
                         'of rows, no unit text)') from None
    if mat.ndim != 2 or not np.all(np.isfinite(mat)):
        raise ValueError(f'{source}: field {key} must be a square matrix of finite numbers in '
                         f'{unit}; remove nan/inf entries')
    return mat


def _vector(value, key, source, n, unit):
    """``value`` as ``n`` finite floats (ValueError naming file, field and fix)."""
    try:
        vec = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise ValueError(f'{source}: field {key} must be a list of {n} numbers in {unit} '
                         '(no unit text)') from None
    if vec.shape != (n,) or not np.all(np.isfinite(vec)):
        raise ValueError(f'{source}: field {key} has {vec.size} entries, expected {n} finite '
                         f'numbers in {unit} (one per DOF of M)')
    return vec


def _dof_index(value, key, source, n):
    """``value`` as a DOF index in 0..n-1 (ValueError naming file, field and fix)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or \
            not 0 <= int(value) < n:
        raise ValueError(f'{source}: field {key}: {value!r} is not a DOF index; give an integer '
                         f'in 0..{n - 1} (DOFs count from 0 in the order of M)')
    return int(value)


def _external_force(value, source, n):
    """Field ``external_force``: a list of n forces [N] or a mapping DOF index -> force [N]."""
    if isinstance(value, dict):
        force = np.zeros(n)
        for dof, val in value.items():
            i = _dof_index(dof, 'external_force', source, n)
            force[i] = _vector([val], f'external_force[{i}]', source, 1, 'N')[0]
        return force
    return _vector(value, 'external_force', source, n, 'N')


def check_symmetric_pd(mat, key, source, semi=False):
    """Raise ValueError unless ``mat`` is symmetric and positive (semi-)definite."""
    scale = max(float(np.max(np.abs(mat))), 1e-300)
    if not np.allclose(mat, mat.T, rtol=0.0, atol=1e-9 * scale):
        i, j = np.unravel_index(np.argmax(np.abs(mat - mat.T)), mat.shape)
        raise ValueError(f'{source}: field {key} is not symmetric ({key}[{i}][{j}] = '
                         f'{mat[i, j]:g} but {key}[{j}][{i}] = {mat[j, i]:g}); make '
                         f'{key}[i][j] equal {key}[j][i]')
    low = float(np.min(np.linalg.eigvalsh(mat)))
    if low < -1e-9 * scale if semi else low <= 1e-12 * scale:
        kind = 'positive semi-definite' if semi else 'positive definite'
        raise ValueError(f'{source}: field {key} is not {kind} (smallest eigenvalue {low:g}); '
                         'check signs and units of its entries (a grounded structure has a '
                         'positive-definite K and M)')


def _damping_matrix(damp, M, K, source):
    """C [N s/m] from the ``damping`` mapping (rayleigh or modal; module docstring)."""
    n = M.shape[0]
    if not isinstance(damp, dict):
        raise ValueError(f'{source}: field damping must be a mapping, e.g. {{type: rayleigh, '
                         'zeta: [0.042, 0.10], modes: [0, 1]}} or {type: modal, zeta: 0.02}')
    unknown = sorted(set(map(str, damp)) - set(DAMPING_KEYS))
    if unknown:
        raise ValueError(f'{source}: unknown key(s) damping.{", damping.".join(unknown)}; use '
                         f'{", ".join(DAMPING_KEYS)}')
    kind = damp.get('type', 'rayleigh')
    if kind not in ('rayleigh', 'modal'):
        raise ValueError(f'{source}: damping.type {kind!r} unknown; use rayleigh or modal')
    zeta = damp.get('zeta', 0.0 if kind == 'modal' else None)
    try:
        zeta = np.atleast_1d(np.asarray(zeta, dtype=float))
    except (TypeError, ValueError):
        zeta = np.array([np.nan])
    allowed = (2,) if kind == 'rayleigh' else (1, n)
    if zeta.size not in allowed or not np.all((zeta >= 0) & (zeta < 1)):
        what = 'two ratios' if kind == 'rayleigh' else f'one ratio or {n} (one per mode)'
        raise ValueError(f'{source}: damping.zeta must list {what} in [0, 1) for {kind} '
                         f'damping (0.05 = 5 %), got {damp.get("zeta")!r}')
    if kind == 'modal':
        return modal_damping(M, K, zeta if zeta.size == n else zeta[0])
    if 'freqs_hz' in damp:
        freqs = _vector(damp['freqs_hz'], 'damping.freqs_hz', source, 2, 'Hz')
        if not np.all(freqs > 0) or freqs[0] == freqs[1]:
            raise ValueError(f'{source}: damping.freqs_hz must be two different positive '
                             f'frequencies [Hz], got {damp["freqs_hz"]!r}')
        f1, f2 = freqs
    else:
        modes = damp.get('modes', [0, 1])
        if not isinstance(modes, (list, tuple)) or len(modes) != 2:
            raise ValueError(f'{source}: damping.modes must list two mode indices (0 = lowest '
                             f'frequency), got {modes!r}')
        i, j = (_dof_index(m, 'damping.modes', source, n) for m in modes)
        if i == j:
            raise ValueError(f'{source}: damping.modes must name two different modes, got '
                             f'{modes!r}')
        f = np.sqrt(np.clip(sla.eigh(K, M, eigvals_only=True), 0, None)) / (2 * math.pi)
        f1, f2 = f[i], f[j]
    a0, a1 = rayleigh_coefficients(f1, f2, zeta[0], zeta[1])
    return a0 * M + a1 * K


def model_from_dict(data, source='model'):
    """Build a :class:`LinearModel` from the YAML layout of the module docstring.

    Every matrix must be finite and symmetric; M and K positive definite, C
    positive semi-definite; unknown keys are errors (a typo would otherwise
    silently drop a setting).  ValueError names the file, the field and the fix.
    """
    if not isinstance(data, dict):
        raise ValueError(f'{source}: expected a mapping with keys M/masses, K, C or damping')
    unknown = sorted(set(map(str, data)) - set(MODEL_KEYS))
    if unknown:
        raise ValueError(f'{source}: unknown key(s) {", ".join(unknown)}; the keys of a model '
                         f'file are {", ".join(MODEL_KEYS)}')
    for pair in (('M', 'masses'), ('C', 'damping')):
        if all(key in data for key in pair):
            raise ValueError(f'{source}: fields {pair[0]} and {pair[1]} are both given; keep '
                             'only one')
    if 'masses' in data:
        try:
            masses = np.asarray(data['masses'], dtype=float).reshape(-1)
        except (TypeError, ValueError):
            raise ValueError(f'{source}: field masses must be a list of numbers in kg') from None
        if masses.size == 0 or not np.all(np.isfinite(masses) & (masses > 0)):
            raise ValueError(f'{source}: field masses must list one positive finite mass [kg] '
                             f'per DOF, got {data["masses"]!r}')
        data = dict(data, M=np.diag(masses).tolist())
        data.pop('masses')
    if 'M' not in data:
        raise ValueError(f'{source}: missing M (kg matrix) or masses (diagonal list)')
    if 'K' not in data:
        raise ValueError(f'{source}: missing K (stiffness matrix, N/m)')
    mats = {}
    for key, unit in (('M', 'kg'), ('K', 'N/m'), ('C', 'N s/m')):
        if key in data:
            mats[key] = _matrix(data, key, source, unit)
            if mats[key].shape[0] != mats[key].shape[1]:
                raise ValueError(f'{source}: field {key} is {mats[key].shape}; it must be '
                                 'square (one row and one column per DOF)')
            if key != 'M' and mats[key].shape != mats['M'].shape:
                raise ValueError(f'{source}: {key} is {mats[key].shape} but M is '
                                 f'{mats["M"].shape}; make them equal')
            check_symmetric_pd(mats[key], key, source, semi=key == 'C')
    M, K = mats['M'], mats['K']
    n = M.shape[0]
    if 'C' in mats:
        C = mats['C']
    else:
        C = _damping_matrix(data.get('damping', {'type': 'modal', 'zeta': 0.0}), M, K, source)
    gamma = _vector(data.get('influence', [1.0] * n), 'influence', source, n, '-')
    force = _external_force(data['external_force'], source, n) \
        if data.get('external_force') is not None else np.zeros(n)
    interface = data.get('interface_dofs', [n - 1])
    if not isinstance(interface, (list, tuple)) or not interface:
        raise ValueError(f'{source}: field interface_dofs must be a non-empty list of DOF '
                         f'indices in 0..{n - 1}, got {interface!r}')
    interface = [_dof_index(i, 'interface_dofs', source, n) for i in interface]
    if len(set(interface)) != len(interface):
        raise ValueError(f'{source}: field interface_dofs {interface} repeats a DOF; list each '
                         'once')
    output = _dof_index(data.get('output_dof', n - 1), 'output_dof', source, n)
    names = data.get('dof_names', [])
    if not isinstance(names, (list, tuple)) or len(names) not in (0, n):
        raise ValueError(f'{source}: field dof_names must list {n} names (one per DOF)')
    return LinearModel(M, C, K, gamma, interface, output, name=str(data.get('name', source)),
                       dof_names=[str(x) for x in names], external_force=force)


def load_model_yaml(path):
    """Read a model YAML file (see the module docstring)."""
    return model_from_dict(yamlfile.load(path), source=str(path))
