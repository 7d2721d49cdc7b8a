"""The maRTHS two-actuator rig simulated: its 2 x 2 control plant and its physical frame.

Moved here from ``rths_bench.marths`` so that the bridge can drive the rig (the
``simulated_rig`` backend) and the benchmark's offline loop uses the same physics.
Numbers: :mod:`rths_common.marths_data` (github.com/FermandoisLab/maRTHS-bmk-RoDeAC, MIT).

* The control plant (``fcn_build_uncert_plant.m``): command strokes [mm] -> measured strokes
  [mm], 2 x 2, one SIMO realisation per column; its uncertain draws keep the static gains
  nominal; ZOH-discretised exactly (:class:`PlantBatch`, a batch of plants at once).
* The physical frame (``physicalFrame_feedbackForce.m``): 5 DOFs, three slave rotations
  condensed on the interface node's (x, theta); its restoring force ``K q + C q' + M q''``
  with backward differences, as the benchmark's Derivative blocks.
* :class:`SimulatedRigBackend`: the bridge backend of the rig: two command channels
  (strokes [m]), two displacement sensors (the plant's measured strokes with the
  benchmark's sensor noise) and two load cells (the frame's force and moment at the node
  as the actuators' axial forces, through :class:`rths_common.coupler.Coupler`).
"""

import math
import warnings

import numpy as np

from rths_common.marths_data import INCH, load_config, rig_coupler  # noqa: F401 (re-exported)

from .backend import Backend
from .channels import zoh as discretise


def _frame_element(e, area, inertia, length, angle):
    """Global 6 x 6 stiffness of a 2-D frame element, axial terms dropped."""
    ei = e * inertia
    k = np.zeros((6, 6))
    bend = ei / length ** 3 * np.array(
        [[12, 6 * length, -12, 6 * length],
         [6 * length, 4 * length ** 2, -6 * length, 2 * length ** 2],
         [-12, -6 * length, 12, -6 * length],
         [6 * length, 2 * length ** 2, -6 * length, 4 * length ** 2]])
    k[np.ix_([1, 2, 4, 5], [1, 2, 4, 5])] = bend
    cs, sn = math.cos(angle), math.sin(angle)
    r = np.array([[cs, sn, 0], [-sn, cs, 0], [0, 0, 1]])
    t = np.kron(np.eye(2), r)
    return t.T @ k @ t


def _modal_damping(m, k, zeta):
    """Damping matrix of ratio ``zeta`` in every mode (frequencies rounded to 0.01 rad/s)."""
    lam, phi = np.linalg.eig(np.linalg.solve(m, k))
    order = np.argsort(np.sqrt(np.real(lam)))
    w = np.round(100 * np.sqrt(np.real(lam[order]))) / 100
    phi = np.real(phi[:, order])
    c = np.zeros_like(m)
    for i in range(m.shape[0]):
        v = phi[:, i]
        c += m @ np.outer(v, v) @ m * (2 * zeta * w[i] / (v @ m @ v))
    return c


def physical_frame(cfg: dict):
    """``(K5, C5, M5, T)`` of the 5-DOF physical frame and the condensation ``T``.

    DOFs: x of the beam, rotations of the interface node, of the other beam end and of
    the two pinned column bases.  ``T`` (3 x 2) gives the three slave rotations from
    (x, theta) by static condensation.
    """
    p = cfg['physical_frame']
    e, lb, lc = p['E_pa'], p['Lb_m'], p['Lc_m']
    ic = p['Ic_in4'] * INCH ** 4 * p['tuning_column']
    ib = p['Ib_m4'] * p['tuning_beam']
    ac = p['Ac_in2'] * INCH ** 2
    col = _frame_element(e, ac, ic, lc, math.pi / 2)   # end 1 base, end 2 top
    beam = _frame_element(e, p['Ab_m2'], ib, lb, 0.0)  # end 1 far node, end 2 interface
    k = np.zeros((5, 5))
    # element DOF (X1, Y1, R1, X2, Y2, R2) -> frame DOF, None where fixed or neglected
    maps = [(col, (None, None, 4, 0, None, 1)),   # column under the interface node
            (col, (None, None, 3, 0, None, 2)),   # column under the far node
            (beam, (None, None, 2, None, None, 1))]
    for ke, dofs in maps:
        for i, gi in enumerate(dofs):
            for j, gj in enumerate(dofs):
                if gi is not None and gj is not None:
                    k[gi, gj] += ke[i, j]
    mass_b, mass_c = p['rho_kg_m3'] * p['Ab_m2'] * lb, p['rho_kg_m3'] * ac * lc
    f = p['mass_factor']
    m = np.diag(np.array([(mass_b + 2 * mass_c) / 2,
                          (mass_b / 2 * lb ** 2 + mass_c / 2 * lc ** 2) / 3,
                          (mass_b / 2 * lb ** 2 + mass_c / 2 * lc ** 2) / 3,
                          mass_c / 2 * lc ** 2 / 3, mass_c / 2 * lc ** 2 / 3]) * f)
    c = _modal_damping(m, k, p['damping'])
    t = -np.linalg.solve(k[2:, 2:], k[2:, :2])
    return k, c, m, t


# ----------------------------------------------------------------------------- plant
def plant_params(cfg: dict) -> dict:
    """Nominal poles/zeros [rad/s] and gains of the 2 x 2 control plant."""
    p = cfg['plant']
    w = 2 * math.pi
    frame = complex(*p['frame_pole_hz']) * w
    c1, c2 = p['col1'], p['col2']
    return {'frame_pole': frame,
            'col1_zeros': [z * w for z in c1['zeros_hz']],
            'col1_poles': [q * w for q in c1['poles_hz']],
            'zero_12': c2['zero_12_hz'] * w, 'zero_22': c2['zero_22_hz'] * w,
            'col2_poles': [q * w for q in c2['poles_hz']],
            'gains': [[c1['gain_11'], c2['gain_12']], [c1['gain_21'], c2['gain_22']]]}


def _zpk_elements(pp: dict) -> list:
    """``[[(z, p, k), ...], ...]`` of the plant's four transfer functions."""
    fp = [pp['frame_pole'], pp['frame_pole'].conjugate()]
    p1 = list(pp['col1_poles']) + fp
    p2 = list(pp['col2_poles']) + fp
    g = pp['gains']
    return [[(pp['col1_zeros'], p1, g[0][0]), ([pp['zero_12']], p2, g[0][1])],
            [(pp['col1_zeros'], p1, g[1][0]), ([pp['zero_22']], p2, g[1][1])]]


def _dc(z, p, k) -> float:
    return float(np.real(k * np.prod(-np.asarray(z)) / np.prod(-np.asarray(p))))


def draw_plant_params(cfg: dict, rng) -> dict:
    """One uncertain plant: normal draws of poles and zeros, static gains kept nominal.

    Standard deviations are fractions of each nominal value (``plant.std``); the two
    transfer functions of a column share their poles, all four share the frame's pair.
    """
    s = cfg['plant']['std']
    nom = plant_params(cfg)
    out = dict(nom)
    out['col1_zeros'] = [z * (1 + s['col1_zeros'] * rng.standard_normal())
                         for z in nom['col1_zeros']]
    out['col1_poles'] = [q * (1 + s['col1_poles'] * rng.standard_normal())
                         for q in nom['col1_poles']]
    out['frame_pole'] = nom['frame_pole'] * (1 + s['frame_pole'] * rng.standard_normal())
    out['zero_12'] = nom['zero_12'] * (1 + s['col2_zeros'] * rng.standard_normal())
    out['col2_poles'] = [q * (1 + s['col2_poles'] * rng.standard_normal())
                         for q in nom['col2_poles']]
    out['zero_22'] = nom['zero_22'] * (1 + s['col2_zeros'] * rng.standard_normal())
    # the benchmark rescales each gain so the low-frequency magnitude stays nominal
    new, old = _zpk_elements(out), _zpk_elements(nom)
    out['gains'] = [[old[i][j][2] * _dc(*old[i][j]) / _dc(*new[i][j]) for j in range(2)]
                    for i in range(2)]
    return out


def plant_state_space(pp: dict):
    """Continuous ``(A, B, C, D)`` of the plant (one SIMO realisation per column)."""
    # lazy: start-up cost: SciPy (~1.5 s) for every `rths` command (the CLI lists this)
    from scipy import signal
    from scipy.linalg import matrix_balance

    els = _zpk_elements(pp)
    blocks = []
    for j in range(2):
        den = np.real(np.poly(els[0][j][1]))
        nums = [np.real(els[i][j][2] * np.poly(els[i][j][0])) for i in range(2)]
        width = den.size
        num = np.array([np.r_[np.zeros(width - n.size), n] for n in nums])
        with warnings.catch_warnings():   # the SIMO numerator's leading zeros
            warnings.simplefilter('ignore', signal.BadCoefficients)
            blocks.append(signal.tf2ss(num, den))
    a = np.zeros((8, 8))
    b = np.zeros((8, 2))
    c = np.zeros((2, 8))
    d = np.zeros((2, 2))
    for j, (aj, bj, cj, dj) in enumerate(blocks):
        s = slice(4 * j, 4 * j + 4)
        a[s, s], b[s, j], c[:, s], d[:, j] = aj, bj[:, 0], cj, dj[:, 0]
    _, (scale, _) = matrix_balance(a, permute=False, separate=True)
    t = np.diag(scale)
    ti = np.linalg.inv(t)
    return ti @ a @ t, ti @ b, c @ t, d


class PlantBatch:
    """The control plants of a batch of runs, ZOH at ``dt``, with sensor noise [mm]."""

    def __init__(self, params: list, dt: float, noise_std_mm: float, rng):
        """Discretise every plant; noise drawn from ``rng``."""
        ss = [plant_state_space(p) for p in params]
        dis = [discretise(a, b, dt) for a, b, _, _ in ss]
        self.ad = np.stack([d[0] for d in dis])
        self.bd = np.stack([d[1] for d in dis])
        self.c = np.stack([s[2] for s in ss])
        self.d = np.stack([s[3] for s in ss])
        self.x = np.zeros((len(params), self.ad.shape[1]))
        self.noise_std = noise_std_mm
        self.rng = rng

    def output(self, u_prev) -> np.ndarray:
        """Measured strokes [mm] (batch, 2) at this tick."""
        y = np.einsum('bij,bj->bi', self.c, self.x) + np.einsum('bij,bj->bi', self.d, u_prev)
        return y + self.noise_std * self.rng.standard_normal(y.shape)

    def advance(self, u):
        """Hold command ``u`` [mm] (batch, 2) over one sample."""
        self.x = np.einsum('bij,bj->bi', self.ad, self.x) + np.einsum('bij,bj->bi', self.bd, u)


def command_volts(cfg: dict, u_mm) -> np.ndarray:
    """Command voltage of strokes ``u_mm`` (..., 2) through the channels' calibration."""
    ch = cfg['channels']
    g = np.asarray(ch['v2d_gain'])
    return u_mm / np.asarray(ch['correction_gain']) / g - np.asarray(ch['v2d_const']) / g


class FrameForce:
    """The physical frame's restoring forces for a batch of interface motions, sample by sample.

    ``step(x, theta)`` (arrays of the batch, m and rad, the coupler's convention) returns
    ``K5 q + C5 q' + M5 q''`` (batch, 5) of the frame: [0] the force on x [N], [1] the moment
    at the interface node [N m], [2] the moment at the beam's far node; ``q`` carries the
    slave rotations condensed on (x, theta); velocity and acceleration are backward
    differences (zero at the first sample), as the benchmark's Derivative blocks.
    """

    def __init__(self, cfg: dict, dt: float, batch: int = 1):
        """Build the 5-DOF frame of ``cfg`` (:func:`physical_frame`) for ``batch`` runs."""
        self.k, self.c, self.m, self.t = physical_frame(cfg)
        self.dt = dt
        self.q_prev = np.zeros((batch, 5))
        self.v_prev = np.zeros((batch, 5))
        self.started = False

    def step(self, x, theta) -> np.ndarray:
        """Return the restoring forces (batch, 5) at this sample's ``x`` [m], ``theta`` [rad]."""
        x, theta = np.atleast_1d(x), np.atleast_1d(theta)
        q = np.column_stack([x, theta, np.column_stack([x, theta]) @ self.t.T])
        if self.started:
            vel = (q - self.q_prev) / self.dt
            acc = (vel - self.v_prev) / self.dt
        else:
            vel = acc = np.zeros_like(q)
            self.started = True
        self.q_prev, self.v_prev = q, vel
        return q @ self.k.T + vel @ self.c.T + acc @ self.m.T


def rig_plants(cfg: dict, n_draws: int, seed: int) -> list:
    """Return the nominal plant then ``n_draws`` uncertain ones drawn from ``seed``.

    The same list as ``rths bench marths --draws n_draws --seed seed`` runs.
    """
    rng = np.random.default_rng(seed)
    return [plant_params(cfg)] + [draw_plant_params(cfg, rng) for _ in range(n_draws)]


#: Parameters of the ``simulated_rig`` backend: key -> (type, default, meaning [unit]).
RIG_PARAMS = {
    'rig_plant_draw': (int, 0, '[-] control plant of the maRTHS rig: 0 = nominal, k > 0 = the '
                       'k-th uncertain plant of rths bench marths --seed rig_seed'),
    'rig_seed': (int, 11, '[-] seed of the uncertain plants (rths bench marths --seed)'),
    'rig_noise_seed': (int, 0, '[-] seed of the displacement sensors\' noise'),
    'rig_sensor_noise': (int, 1, "[-] 1 = the benchmark's band-limited sensor noise on the "
                         'strokes (power noise_power at 1/fs); 0 = none'),
}
RIG_RANGES = {'rig_plant_draw': (0, 1000), 'rig_sensor_noise': (0, 1)}


class SimulatedRigBackend(Backend):
    """The maRTHS two-actuator rig, simulated: each ``write()`` advances one sample.

    Channel i is actuator i of the benchmark's coupler.  ``write`` takes the command
    strokes [m]; ``read`` returns the measured strokes [m] (the plant's output, with
    sensor noise) and the load cells' axial forces [N]: the physical frame's force and
    moment at the interface node, driven by the measured strokes through the coupler's
    exact inverse (as the virtual benchmark does), as axial forces ``J(theta)^-T (F, M)``.
    """

    summary = "simulated maRTHS rig: two actuators, coupler, 2 x 2 plant, frame (marths_rig.py)"
    params = RIG_PARAMS
    ranges = RIG_RANGES
    in_process = True

    def _configure(self, params: dict):
        cfg = load_config()
        self.cfg = cfg
        get = {k: params.get(k, default) for k, (_, default, _) in RIG_PARAMS.items()}
        draw = get['rig_plant_draw']
        if isinstance(draw, bool) or int(draw) != draw or not 0 <= draw <= 1000:
            raise ValueError(f'parameter rig_plant_draw = {draw!r} must be an integer in '
                             '[0, 1000] (0 = the nominal plant)')
        self.plant_params = rig_plants(cfg, int(draw), int(get['rig_seed']))[int(draw)]
        self.coupler = rig_coupler(cfg)
        self.dt = 1.0 / self.limits.fs_hz
        self.noise_std_mm = (math.sqrt(cfg['channels']['noise_power'] / self.dt)
                             if int(get['rig_sensor_noise']) else 0.0)
        self.noise_seed = int(get['rig_noise_seed'])
        self.n_channels = self.coupler.n
        self._last = None

    def _activate(self):
        self.plant = PlantBatch([self.plant_params], self.dt, self.noise_std_mm,
                                np.random.default_rng(self.noise_seed))
        self.frame = FrameForce(self.cfg, self.dt)
        self._last = None

    def _deactivate(self):
        """Nothing to stop: the plant advances only when written to."""

    def _write(self, command):
        u_mm = 1000.0 * np.asarray(command, float).reshape(1, -1)
        self.plant.advance(u_mm)
        strokes = self.plant.output(u_mm)[0] / 1000.0
        x, theta = self.coupler.dofs(strokes, iterations=2)
        f5 = self.frame.step(x, theta)[0]
        self._last = (strokes, self.coupler.axial_forces(f5[0], f5[1], theta))

    def _read(self, wait_s=None):
        if self._last is None:
            raise RuntimeError('read() before the first write()')
        return self._last[0].copy(), self._last[1].copy()
