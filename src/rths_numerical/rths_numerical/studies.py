"""DTM parameter studies of seed chapter 7, vectorised in the frequency domain.

Method: the building is linear with Rayleigh (hence modal) damping, so its
receptances follow from the undamped modes ``phi_j`` (mass-normalised)::

    h_ab(w)  = sum_j phi_aj phi_bj / (w_j^2 - w^2 + 2 i zeta_j w_j w)     (force b -> disp a)
    H_a(w)   = -sum_j phi_aj (phi_j^T M Gamma) / (same)                   (a_g -> disp a)

A DTM on the interface DOF I is a base-excited SDOF (seed eq. 46) whose force
on the floor is ``-M_app(w) A_I``, with the absolute floor acceleration
``A_I = -w^2 U_I + A_g`` and the apparent mass
``M_app = m_d (k_d + i w c_d) / (k_d - w^2 m_d + i w c_d)``.  Eliminating the
force gives one complex scalar per frequency::

    U_I = (H_I - h_II M_app) A_g / (1 - w^2 h_II M_app)
    U_o = H_o A_g - h_oI M_app (-w^2 U_I + A_g)

so whole grids of (building frequency, mass ratio) or (DTM frequency,
damping) are evaluated with batched numpy arithmetic and one inverse FFT per
grid point (the record is zero-padded so the free decay after it fits, no
wrap-around).  ``test_studies.py`` checks this against the time-domain
reference (:func:`.reference.simulate_reference`).

Section 7.1: the first building frequency is changed by scaling K by
``s^2`` (mode shapes and the damping ratios of every mode are unchanged,
since Rayleigh ``a0, a1`` scale with ``s`` and ``1/s``); the mass ratio scales
the DTM's m_d, c_d, k_d together (its f_n and zeta stay those of Table 4);
the DTM frames are left out.

Den Hartog's optimum (undamped primary SDOF, harmonic force), mass ratio mu::

    f_opt / f_1 = 1 / (1 + mu),    zeta_opt = sqrt(3 mu / (8 (1 + mu)^3))

and for ground-acceleration excitation (Warburton 1982)::

    f_opt / f_1 = sqrt(1 - mu/2) / (1 + mu),  zeta_opt = sqrt(3 mu / (8 (1 + mu)(1 - mu/2)))

``mu`` is the DTM mass over the building's first-mode effective mass (the
equivalent SDOF), reported beside the seed's mass-ratio definition.
"""

import math

import numpy as np

from .dtm import SEED_CONFIGURATION, DTMParameters, dtm_configuration
from .model import LinearModel

CRITERIA = ('max_disp', 'max_accel', 'rms_disp', 'rms_accel')


def den_hartog(mu):
    """Den Hartog optimum ``(f_ratio, zeta)`` for a harmonic force on an undamped SDOF."""
    return 1.0 / (1.0 + mu), math.sqrt(3 * mu / (8 * (1 + mu) ** 3))


def warburton_ground(mu):
    """Optimum ``(f_ratio, zeta)`` for ground-acceleration excitation (Warburton 1982)."""
    return math.sqrt(1 - mu / 2) / (1 + mu), math.sqrt(3 * mu / (8 * (1 + mu) * (1 - mu / 2)))


class ModalBuilding:
    """Receptances of a Rayleigh/modally damped model at its interface and output DOFs."""

    def __init__(self, model: LinearModel, n_modes=None):
        """Compute modes and modal damping ratios (from C projected on the modes)."""
        f, phi = model.modes()
        w = 2 * math.pi * f
        zeta = np.diag(phi.T @ model.C @ phi) / (2 * w)
        keep = slice(None) if n_modes is None else np.argsort(f)[:n_modes]
        self.w = w[keep]
        self.zeta = zeta[keep]
        self.phi = phi[:, keep]
        self.part = self.phi.T @ model.M @ model.gamma
        self.iface = model.interface_dofs[0]
        self.out = model.output_dof
        self.gamma_out = model.gamma[self.out]
        eff = self.part ** 2
        self.f1 = float(self.w[np.argmax(eff)] / (2 * math.pi))
        j = np.argmax(eff)
        # equivalent SDOF mass of the first x mode seen at the interface (phi_I = 1)
        self.modal_mass_iface = float(1.0 / self.phi[self.iface, j] ** 2)

    def receptances(self, omega, stiffness_scale=1.0):
        """Return ``H_I, H_o, h_II, h_oI`` at ``omega`` [rad/s] (broadcasts with the scale)."""
        s = np.asarray(stiffness_scale, dtype=float)[..., None, None]
        wj = self.w * s
        den = wj ** 2 - omega[..., None] ** 2 + 2j * self.zeta * wj * omega[..., None]
        pi, po = self.phi[self.iface], self.phi[self.out]
        H_I = -(pi * self.part / den).sum(-1)
        H_o = -(po * self.part / den).sum(-1)
        h_II = (pi * pi / den).sum(-1)
        h_oI = (po * pi / den).sum(-1)
        return H_I, H_o, h_II, h_oI


def _apparent_mass(omega, m_d, c_d, k_d):
    m_d, c_d, k_d = (np.asarray(x, dtype=float)[..., None] for x in (m_d, c_d, k_d))
    iw = 1j * omega
    num = m_d * (k_d + iw * c_d)
    den = k_d - omega ** 2 * m_d + iw * c_d
    # no DTM (m_d = c_d = k_d = 0): apparent mass 0
    return np.divide(num, den, out=np.zeros(np.broadcast(num, den).shape, complex),
                     where=(den != 0))


def coupled_response(building: ModalBuilding, ag, dt, m_d, c_d, k_d, stiffness_scale=1.0,
                     pad_s=30.0):
    """2nd-floor displacement and absolute acceleration histories for arrays of DTM parameters.

    ``m_d, c_d, k_d`` (and ``stiffness_scale``) broadcast to a grid shape G;
    returns ``(disp, accel_abs)`` of shape ``G + (len(ag),)``.  ``m_d = 0``
    gives the uncontrolled building.
    """
    ag = np.asarray(ag, dtype=float)
    n = ag.size
    nfft = int(2 ** math.ceil(math.log2(n + int(pad_s / dt))))
    A = np.fft.rfft(ag, nfft)
    omega = 2 * math.pi * np.fft.rfftfreq(nfft, dt)
    shape = np.broadcast(np.asarray(m_d), np.asarray(c_d), np.asarray(k_d),
                         np.asarray(stiffness_scale)).shape
    scale = (float(stiffness_scale) if np.ndim(stiffness_scale) == 0
             else np.broadcast_to(np.asarray(stiffness_scale, dtype=float), shape))
    H_I, H_o, h_II, h_oI = building.receptances(omega, scale)
    Mapp = _apparent_mass(omega, np.broadcast_to(m_d, shape), np.broadcast_to(c_d, shape),
                          np.broadcast_to(k_d, shape))
    w2 = omega ** 2
    U_I = (H_I - h_II * Mapp) / (1 - w2 * h_II * Mapp)
    U_o = H_o - h_oI * Mapp * (-w2 * U_I + 1.0)
    disp = np.fft.irfft(U_o * A, nfft)[..., :n]
    acc = np.fft.irfft(-w2 * U_o * A, nfft)[..., :n] + building.gamma_out * ag
    return disp, acc


def _criteria(disp, acc):
    return {
        'max_disp': np.max(np.abs(disp), -1), 'max_accel': np.max(np.abs(acc), -1),
        'rms_disp': np.sqrt(np.mean(disp ** 2, -1)), 'rms_accel': np.sqrt(np.mean(acc ** 2, -1)),
    }


def building_frequency_study(model: LinearModel, ag, dt, f1_hz, mass_ratios,
                             damper=SEED_CONFIGURATION, progress=None, surfaces=None):
    """Seed 7.1: criteria on the grid (f1 of the building) x (DTM mass / building mass).

    Returns ``{criterion: array (len(f1_hz), len(mass_ratios))}`` plus the axes.
    ``surfaces(f1_hz, mass_ratios)``, when given, computes the criteria instead of the
    loop here (the study runner: ``rths_study``), the same numbers to rounding.
    """
    building = ModalBuilding(model)
    dtm = damper if isinstance(damper, DTMParameters) else dtm_configuration(damper)
    total = float(model.gamma @ model.M @ model.gamma)
    f1_hz = np.asarray(f1_hz, dtype=float)
    mass_ratios = np.asarray(mass_ratios, dtype=float)
    if surfaces is not None:
        out = {c: np.asarray(v, dtype=float) for c, v in surfaces(f1_hz, mass_ratios).items()}
        out.update(f1_hz=f1_hz, mass_ratios=mass_ratios, building_mass_kg=total)
        return out
    out = {c: np.zeros((f1_hz.size, mass_ratios.size)) for c in CRITERIA}
    factor = mass_ratios * total / dtm.m_d
    for i, f1 in enumerate(f1_hz):
        s = f1 / building.f1
        disp, acc = coupled_response(building, ag, dt, dtm.m_d * factor, dtm.c_d * factor,
                                     dtm.k_d * factor, s)
        for c, v in _criteria(disp, acc).items():
            out[c][i] = v
        if progress:
            progress(i + 1, f1_hz.size)
    out.update(f1_hz=f1_hz, mass_ratios=mass_ratios, building_mass_kg=total)
    return out


def dtm_tuning_study(model: LinearModel, ag, dt, fn_hz, zetas, mass_ratio=0.01, f1_hz=2.81,
                     progress=None, surfaces=None):
    """Seed 7.2: criteria on the grid (DTM f_n) x (DTM zeta) for a building with ``f1_hz``.

    ``surfaces(fn_hz, zetas)``, when given, computes the criteria instead of the loop
    here (the study runner: ``rths_study``), the same numbers to rounding.
    """
    building = ModalBuilding(model)
    total = float(model.gamma @ model.M @ model.gamma)
    m_d = mass_ratio * total
    fn_hz = np.asarray(fn_hz, dtype=float)
    zetas = np.asarray(zetas, dtype=float)
    s = f1_hz / building.f1
    if surfaces is not None:
        out = {c: np.asarray(v, dtype=float) for c, v in surfaces(fn_hz, zetas).items()}
    else:
        out = {c: np.zeros((fn_hz.size, zetas.size)) for c in CRITERIA}
        for i, fn in enumerate(fn_hz):
            w = 2 * math.pi * fn
            disp, acc = coupled_response(building, ag, dt, m_d, 2 * zetas * m_d * w,
                                         m_d * w * w, s)
            for c, v in _criteria(disp, acc).items():
                out[c][i] = v
            if progress:
                progress(i + 1, fn_hz.size)
    unc_d, unc_a = coupled_response(building, ag, dt, 0.0, 0.0, 1.0, s)
    out['uncontrolled'] = {c: float(v) for c, v in _criteria(unc_d, unc_a).items()}
    optima = {}
    for c in CRITERIA:
        i, j = np.unravel_index(np.argmin(out[c]), out[c].shape)
        optima[c] = {'fn_hz': float(fn_hz[i]), 'zeta': float(zetas[j]),
                     'value': float(out[c][i, j])}
    mu_modal = m_d / building.modal_mass_iface
    dh = den_hartog(mu_modal)
    wb = warburton_ground(mu_modal)
    out.update(fn_hz=fn_hz, zetas=zetas, optima=optima, building_mass_kg=total, m_d_kg=m_d,
               mass_ratio=mass_ratio, f1_hz=f1_hz, mu_modal=mu_modal,
               den_hartog={'fn_hz': dh[0] * f1_hz, 'zeta': dh[1]},
               warburton_ground={'fn_hz': wb[0] * f1_hz, 'zeta': wb[1]})
    return out
