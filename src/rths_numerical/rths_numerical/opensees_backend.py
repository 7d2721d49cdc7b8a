"""OpenSeesPy as the numerical substructure (``backend: opensees``), optional.

OpenSeesPy is not open-source for commercial use (see the README); install it
with ``make setup-opensees``.  Everything else in rths works without it.

The model lives in OpenSees' one global domain; each loop step does::

    updateParameter(force parameter, -force_scale * f_k)     # measured force of step k
    analyze(1, dt)                                            # CentralDifference
    u_{k+1} = nodeDisp(interface node)

The measured force enters through ``parameter(..., 'loadPattern', p,
'loadAtNode', node, dof)`` on a Plain pattern with a Constant series; the
ground acceleration through a Plain pattern with a Path series sampled at the
loop steps.  ``CentralDifference`` solves equilibrium at step k for the
displacement of step k+1, so the force of step k pairs with the displacement of
step k+1: the RTHS step, exactly as the built-in ``central_difference``
(``newmark`` is offered for comparison; it lags the force by one step).

A :class:`.model.LinearModel` (``sdof``, ``building2story``, a model YAML) is
built from zeroLength springs (Elastic material, stiffness ``E`` and damping
``eta``): OpenSees has no general matrix element, and node masses are
diagonal, so a model with a coupled mass matrix is first written in coordinates
``u = S q`` that keep the interface DOFs (``u_I = q_I``) and make ``S^T M S``
diagonal (the other DOFs: a Cholesky factor of their mass block, M-orthogonal
to the interface).  Then ``S^T K S`` and ``S^T C S`` are assembled exactly:
a spring between nodes i and j of ``-K_ij``, a spring to ground of the row sum.
"""

import ctypes
import glob
from importlib.metadata import version
import importlib.util
import os

import numpy as np

from .ground_motion import integrate
from .integrators import check_central_difference_step
from .model import LinearModel
from .stepping import SteppedSubstructure

#: Integrators of this backend (OpenSees names them CentralDifference and Newmark).
OPENSEES_INTEGRATORS = ('central_difference', 'newmark')
INSTALL_HINT = ('install it with `make setup-opensees` (openseespy==3.7.1.2 on Python 3.11; '
                'openseespy==3.8.0.0 on Python >= 3.12)')
_OPS = None
_OWNER = None   # the substructure whose model is in OpenSees' (global) domain


def _preload_bundled_libraries():
    """Load the BLAS/LAPACK shipped in the openseespylinux wheel (it does not find them itself).

    Returns the list of libraries loaded (empty when the wheel has none, e.g. on
    Windows or macOS, or a system BLAS is used).
    """
    spec = importlib.util.find_spec('openseespylinux')
    if spec is None or not spec.origin:
        return []
    libdir = os.path.join(os.path.dirname(spec.origin), 'lib')
    loaded = []
    # dependencies first: gfortran/quadmath before BLAS, BLAS before LAPACK
    for pattern in ('libquadmath.so*', 'libgfortran.so*', 'libblas.so*', 'liblapack.so*'):
        for path in sorted(glob.glob(os.path.join(libdir, pattern))):
            try:
                ctypes.CDLL(path, mode=ctypes.RTLD_GLOBAL)
                loaded.append(path)
            except OSError:
                pass   # the import below reports what is still missing
    return loaded


def import_opensees():
    """Return the ``openseespy.opensees`` module, preloading the wheel's BLAS first.

    Raises OSError naming the fix when OpenSeesPy is absent or will not load.
    """
    global _OPS
    if _OPS is not None:
        return _OPS
    if importlib.util.find_spec('openseespy') is None:
        raise OSError(f'backend opensees: OpenSeesPy is not installed; {INSTALL_HINT}')
    loaded = _preload_bundled_libraries()
    try:
        # lazy: optional: tried here, refused with a clear message when missing
        import openseespy.opensees as ops
    except (ImportError, RuntimeError, OSError) as err:
        cause = err.__cause__ or err.__context__ or err
        raise OSError(
            f'backend opensees: importing OpenSeesPy failed ({cause}); preloaded '
            f'{len(loaded)} bundled librar{"y" if len(loaded) == 1 else "ies"}. Install a system '
            'BLAS/LAPACK (Debian: apt-get install libblas3 liblapack3) or reinstall: '
            f'{INSTALL_HINT}') from None
    _OPS = ops
    return ops


def opensees_available():
    """Return ``(True, version)`` or ``(False, reason)`` without raising (for test skips)."""
    try:
        import_opensees()
    except OSError as err:
        return False, str(err)
    return True, version('openseespy')


def mass_decoupling(M, keep):
    """Return ``S`` with ``u = S q``: ``S^T M S`` diagonal and ``u_i = q_i`` for ``i in keep``.

    Raises ValueError if the kept DOFs are mass-coupled among themselves.
    """
    M = np.asarray(M, dtype=float)
    n = M.shape[0]
    keep = [int(i) for i in keep]
    off = M - np.diag(np.diag(M))
    if not np.any(off):
        return np.eye(n)
    other = [i for i in range(n) if i not in keep]
    S = np.zeros((n, n))
    S[keep, keep] = 1.0
    if other:
        m_oo = M[np.ix_(other, other)]
        S[np.ix_(other, keep)] = -np.linalg.solve(m_oo, M[np.ix_(other, keep)])
        S[np.ix_(other, other)] = np.linalg.inv(np.linalg.cholesky(m_oo)).T
    mq = S.T @ M @ S
    block = mq[np.ix_(keep, keep)]
    if np.max(np.abs(block - np.diag(np.diag(block)))) > 1e-12 * np.max(np.abs(block)):
        raise ValueError('backend opensees: the interface DOFs are coupled by the mass matrix; '
                         'OpenSees node masses are diagonal: use backend builtin')
    return S


def linear_model_builder(model: LinearModel, interface_dofs):
    """Return a builder of ``model`` in OpenSees from zeroLength springs (module docstring)."""
    S = mass_decoupling(model.M, interface_dofs)
    mq, kq, cq = (S.T @ mat @ S for mat in (model.M, model.K, model.C))
    n = model.n

    def build(ops):
        ops.model('basic', '-ndm', 1, '-ndf', 1)
        ground = n + 1
        ops.node(ground, 0.0)
        ops.fix(ground, 1)
        for i in range(n):
            ops.node(i + 1, 0.0, '-mass', float(mq[i, i]))
        tag = 0
        for i in range(n):
            for j in range(i + 1, n):
                if kq[i, j] or cq[i, j]:
                    tag += 1
                    ops.uniaxialMaterial('Elastic', tag, -float(kq[i, j]), -float(cq[i, j]))
                    ops.element('zeroLength', tag, i + 1, j + 1, '-mat', tag, '-dir', 1)
            tag += 1
            ops.uniaxialMaterial('Elastic', tag, float(kq[i].sum()), float(cq[i].sum()))
            ops.element('zeroLength', tag, ground, i + 1, '-mat', tag, '-dir', 1)
        return {'interface': [(int(i) + 1, 1) for i in interface_dofs],
                'dof_nodes': [(i, 1) for i in range(1, n + 1)], 'transform': S,
                'system': 'FullGeneral'}
    return build


class ScriptModel:
    """What the substructure needs to know of a model built by a user script (one DOF).

    The interface DOF is the script's ``interface_node``/``interface_dof``; it
    is also the output DOF (the review's "2nd floor"); ``gamma`` is 1 when the
    ground moves along it (``ground_dof``), else 0.
    """

    n = 1
    interface_dofs = (0,)
    output_dof = 0
    has_external_force = False

    def __init__(self, path, gamma=1.0):
        """Name the model after its script."""
        self.path = path
        self.name = os.path.splitext(os.path.basename(path))[0]
        self.gamma = np.array([float(gamma)])
        self.dof_names = ['interface']


def load_model_script(path):
    """Import the user's model script at ``path``; return its ``build`` (ValueError if none)."""
    if not os.path.isfile(path):
        raise ValueError(f'parameter model = {path!r}: model script not found')
    spec = importlib.util.spec_from_file_location(f'rths_model_{abs(hash(path))}', path)
    module = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(module)
    except Exception as err:  # the user's code: report any failure as a bad model
        raise ValueError(f'model script {path}: importing it failed: '
                         f'{type(err).__name__}: {err}') from None
    build = getattr(module, 'build', None)
    if not callable(build):
        raise ValueError(f'model script {path}: define a function build(ops) that builds the '
                         'model and returns {"interface_node": N, "interface_dof": D} '
                         '(README, "Your own OpenSees model")')
    return build


def script_builder(path):
    """Return ``(builder, ground_dof)`` for the model script at ``path`` (checked once here)."""
    build = load_model_script(path)
    ops = import_opensees()

    def builder(ops):
        try:
            out = build(ops)
        except Exception as err:  # the user's code
            raise ValueError(f'model script {path}: build(ops) failed: '
                             f'{type(err).__name__}: {err}') from None
        return _check_script_result(path, out, ops)
    ops.wipe()
    ground = builder(ops)['ground_dof']
    ops.wipe()
    return builder, ground


def _check_script_result(path, out, ops):
    """Validate what ``build(ops)`` returned; return the backend's spec."""
    where = f'model script {path}: build(ops) must return'
    if not isinstance(out, dict):
        raise ValueError(f'{where} a dict with interface_node and interface_dof, '
                         f'not {type(out).__name__}')
    for key in ('interface_node', 'interface_dof'):
        if not isinstance(out.get(key), int) or isinstance(out.get(key), bool):
            raise ValueError(f'{where} an integer {key} (got {out.get(key)!r})')
    node, dof = out['interface_node'], out['interface_dof']
    if node not in ops.getNodeTags():
        raise ValueError(f'{where} an existing interface_node: node {node} is not in the model '
                         f'(nodes {sorted(ops.getNodeTags())})')
    ndf = len(ops.nodeDisp(node))
    ground = out.get('ground_dof', 1)
    for key, value in (('interface_dof', dof), ('ground_dof', ground)):
        if not isinstance(value, int) or not 1 <= value <= ndf:
            raise ValueError(f'{where} {key} in 1..{ndf} (node {node} has {ndf} DOFs), '
                             f'got {value!r}')
    hinge = out.get('hinge')
    if hinge is not None and (not isinstance(hinge, (tuple, list)) or len(hinge) != 2
                              or hinge[0] not in ops.getEleTags()):
        raise ValueError(f'{where} hinge as (element tag, section number) of an existing '
                         f'element, got {hinge!r}')
    return {'interface': [(node, dof)], 'dof_nodes': [(node, dof)], 'transform': np.eye(1),
            'ndf': ndf, 'ground_dof': ground, 'hinge': hinge,
            'hinge_length_m': float(out.get('hinge_length_m', 1.0)),
            'system': out.get('system', 'FullGeneral')}


class OpenSeesSubstructure(SteppedSubstructure):
    """A model built in OpenSeesPy, stepped by the RTHS loop (module docstring).

    ``builder(ops)`` builds the model (nodes, elements, masses) and returns a
    dict: ``interface`` [(node, dof)], ``dof_nodes`` (the node of each model
    DOF, 1 DOF each) and ``transform`` ``S`` (``u = S q``).  ``loads`` are the
    per-DOF load vectors [N per unit] of the ground acceleration ``a_g`` and of
    the external force scale, in the model's coordinates ``u``.
    """

    backend = 'opensees'

    def __init__(self, builder, model: LinearModel, ground_accel, dt,
                 integrator='central_difference', interface_dofs=None, force_scale=1.0,
                 interface_frame='absolute', specimen_mass_kg=0.0, ground_disp=None):
        """Check the settings and build the model in OpenSees."""
        if integrator not in OPENSEES_INTEGRATORS:
            raise ValueError(f'parameter integrator = {integrator!r}: backend opensees offers '
                             f'{", ".join(OPENSEES_INTEGRATORS)}')
        if interface_frame not in ('absolute', 'relative'):
            raise ValueError(f'interface_frame {interface_frame!r}: use absolute or relative')
        self.ops = import_opensees()
        self.model = model
        self.integrator = integrator
        self.dt = float(dt)
        self.ag = np.asarray(ground_accel, dtype=float)
        self.n_steps = int(self.ag.size)
        if self.n_steps < 2:
            raise ValueError('the ground motion has fewer than 2 steps; check duration_s')
        self._linear = isinstance(model, LinearModel)
        if integrator == 'central_difference' and self._linear:
            check_central_difference_step(model.M, model.K, self.dt)
        self.ug = (integrate(self.ag, self.dt)[1] if ground_disp is None
                   else np.asarray(ground_disp, dtype=float))
        self.iface = [int(i) for i in (model.interface_dofs if interface_dofs is None
                                       else interface_dofs)]
        self.n_interface = len(self.iface)
        self.force_scale = float(force_scale)
        self.frame = interface_frame
        self._gi = model.gamma[self.iface]
        # the specimen's ground term P_I^E (relative frame), and for a linear model -M Gamma
        self._specimen_ground = (self.force_scale * float(specimen_mass_kg) * self._gi
                                 if interface_frame == 'relative' else np.zeros(len(self.iface)))
        ground = np.zeros(model.n)
        if self._linear:
            ground = model.M @ model.gamma
            ground[self.iface] += self._specimen_ground
        self._ground_load = -ground
        self._builder = builder
        self.reset()

    def _apply_patterns(self, spec):
        ops, S = self.ops, spec['transform']
        nodes = spec['dof_nodes']
        # a trailing 0: time at the last step may pass (n-1) dt by round-off; 0 from step n on
        ops.timeSeries('Path', 1, '-dt', self.dt, '-values', *self.ag.tolist(), 0.0)
        ndf = spec.get('ndf', 1)
        if self._linear:
            ops.pattern('Plain', 1, 1)
            for (node, _), value in zip(nodes, S.T @ self._ground_load, strict=True):
                if value:
                    ops.load(node, float(value))
        else:   # a script model: every mass feels the ground acceleration along ground_dof
            ops.pattern('UniformExcitation', 1, spec['ground_dof'], '-accel', 1)
            if np.any(self._specimen_ground):
                ops.pattern('Plain', 4, 1)
                for (node, dof), value in zip(spec['interface'], self._specimen_ground,
                                              strict=True):
                    load = [0.0] * ndf
                    load[dof - 1] = -float(value)
                    ops.load(node, *load)
        if self.model.has_external_force:
            scale = self.model.external_force_scale(np.arange(self.n_steps) * self.dt)
            ops.timeSeries('Path', 3, '-dt', self.dt, '-values', *scale.tolist(), 0.0)
            ops.pattern('Plain', 3, 3)
            for (node, _), value in zip(nodes, S.T @ self.model.external_force, strict=True):
                if value:
                    ops.load(node, float(value))
        ops.timeSeries('Constant', 2)
        ops.pattern('Plain', 2, 2)
        for i, (node, dof) in enumerate(spec['interface']):
            ops.load(node, *([0.0] * ndf))
            ops.parameter(i + 1, 'loadPattern', 2, 'loadAtNode', node, dof)

    def reset(self):
        """Rebuild the model at rest in OpenSees (step 0)."""
        global _OWNER
        ops = self.ops
        ops.wipe()
        spec = self._builder(ops)
        self._apply_patterns(spec)
        ops.constraints('Plain')
        ops.numberer('Plain')
        ops.system(spec.get('system', 'FullGeneral'))
        ops.algorithm('Linear', '-factorOnce')
        if self.integrator == 'central_difference':
            ops.integrator('CentralDifference')
        else:
            ops.integrator('Newmark', 0.5, 0.25)
        ops.analysis('Transient')
        _OWNER = self
        self._spec = spec
        self._S = spec['transform']
        self._nodes = spec['dof_nodes']
        self._iface_nodes = spec['interface']
        self._iface_in_u = all(np.array_equal(self._S[i], np.eye(self.model.n)[i])
                               for i in self.iface)
        n, ns = self.model.n, self.n_steps
        self._k = 0
        self._q = np.zeros((ns + 1, n))
        self._hinge = spec.get('hinge')
        self._hinge_mk = np.zeros((ns, 2))    # section moment [N m], curvature [1/m]
        self._cmd = np.zeros((ns, self.n_interface))
        self._force = np.zeros((ns, self.n_interface))
        self._cmd[0] = self._command(np.zeros(n), 0)

    def _command(self, u, k):
        d = u[self.iface] if u.size == self.model.n else u
        if self.frame == 'absolute':
            d = d + self._gi * (self.ug[k] if k < self.n_steps else self.ug[-1])
        return d

    def first_displacement(self) -> np.ndarray:
        """Interface displacement command of step 0 [m] (structure at rest)."""
        return self._cmd[0].copy()

    def advance(self, measured_force) -> np.ndarray:
        """Finish step k with its measured force [N]; return the command of step k+1 [m]."""
        f = self.force_of(measured_force)
        if _OWNER is not self:
            raise RuntimeError('another OpenSees model was built since this one: OpenSees holds '
                               'one model per process; call reset() to rebuild this one')
        ops, k = self.ops, self._k
        for i in range(self.n_interface):
            ops.updateParameter(i + 1, -self.force_scale * float(f[i]))
        if ops.analyze(1, self.dt) != 0:
            raise RuntimeError(f'OpenSees analyze failed at step {k}')
        q = self._q[k + 1]
        for j, (node, dof) in enumerate(self._nodes):
            q[j] = ops.nodeDisp(node, dof)
        if not np.all(np.isfinite(q)) or np.max(np.abs(q)) > 1e6:
            raise RuntimeError(f'OpenSees model diverged at step {k} (|u| = {np.max(np.abs(q))}): '
                               'with CentralDifference every DOF needs a mass and dt < 2/omega_max')
        if self._hinge is not None:
            ele, sec = self._hinge
            self._hinge_mk[k] = (ops.eleResponse(ele, 'section', sec, 'force')[-1],
                                 ops.eleResponse(ele, 'section', sec, 'deformation')[-1])
        self._force[k] = f
        self._k = k + 1
        cmd = self._command(self._S @ q if not self._iface_in_u else q, k + 1)
        if k + 1 < self.n_steps:
            self._cmd[k + 1] = cmd
        return cmd

    def done(self) -> bool:
        """Return True once ``n_steps`` steps are finished."""
        return self._k >= self.n_steps

    def _displacements(self, upto):
        """Model displacements [m] of steps 0..upto-1 (``u = S q``)."""
        return self._q[:upto] @ self._S.T

    def state(self) -> dict:
        """Step count, time [s], interface and output displacement [m] of the last finished step."""
        k = self._k
        u = self._displacements(k)[-1] if k else np.full(self.model.n, np.nan)
        return {'step': k, 'time': (k - 1) * self.dt if k else float('nan'),
                'interface_disp': u[self.iface].copy(),
                'output_disp': float(u[self.model.output_dof])}

    def history(self) -> dict:
        """Arrays of the finished steps (SI units), as :meth:`.NumericalSubstructure.history`.

        Accelerations are central differences of the displacements (what
        CentralDifference uses; for ``newmark`` an approximation).
        """
        k = self._k
        d = self._displacements(k + 1 if k else 0)
        out = self.model.output_dof
        acc = np.zeros(k)
        if k:
            prev = np.concatenate([[0.0], d[:-1, out]])
            acc = ((d[1:, out] - 2 * d[:-1, out] + prev[:-1]) / self.dt ** 2)[:k]
        d = d[:k]
        extra = {}
        if self._hinge is not None:
            extra = {'hinge_moment': self._hinge_mk[:k, 0].copy(),
                     'hinge_rotation': self._hinge_mk[:k, 1] * self._spec['hinge_length_m']}
        return {
            **extra,
            'time': np.arange(k) * self.dt,
            'ground_accel': self.ag[:k].copy(),
            'ground_disp': self.ug[:k].copy(),
            'displacements': d.copy(),
            'output_disp': d[:, out].copy(),
            'output_accel_abs': acc + self.model.gamma[out] * self.ag[:k],
            'interface_disp': d[:, self.iface].copy(),
            'command': self._cmd[:k].copy(),
            'measured_force': self._force[:k].copy(),
        }
