"""Simulated plant: servo-hydraulic actuator -> shake table -> specimen (seed ch. 4-5).

Continuous-time model (default)
-------------------------------
Actuator (seed eq. 3, Table 1; unit DC gain, from
:func:`rths_compensator.plants.continuous_actuator`)::

    X_s(s) / U(s) = G_a(s) = K / prod_i (s - p_i)                          (3, Table 1)

with ``u`` the command [m] and ``x_s`` the shake-table (= supporting frame)
displacement [m].  Both Table 1 models have relative degree >= 3, so the table
velocity ``s G_a`` and acceleration ``xdd_s = s^2 G_a U`` are proper and follow
from the actuator state ``q``: ``x_s = C q``, ``xd_s = C A q``,
``xdd_s = C A^2 q + C A B u``.

The specimen is the entry ``specimen`` names in :data:`rths_numerical.specimens.SPECIMENS`:
a mass on the table (the DTM), a device between the table and the ground (the MR damper)
or nothing (the bare table).

DTM on the table (seed eq. 44-47, Table 4; the model is
:meth:`rths_numerical.dtm.DTMParameters.state_space`)::

    m_d xdd_d + c_1 xd_d2s + k_1 x_d2s + (c_v xd_d2s + k_v x_d2s) = 0          (44)
    m_d xdd_d + c_d xd_d2s + k_d x_d2s = 0,  c_d = c_1 + c_v, k_d = k_1 + k_v  (45)
    m_d xdd_d2s + c_d xd_d2s + k_d x_d2s = -m_d xdd_s                          (46)
    X_d2s(s) / Xdd_s(s) = -m_d / (m_d s^2 + c_d s + k_d)                      (47)

Measured force (project convention): the force the table applies to the
specimen through the four load cells, i.e. the restoring force the specimen
returns to the structure::

    f = m_frame xdd_s + m_d xdd_d = m_frame xdd_s - (c_d xd_d2s + k_d x_d2s) [- f_c]

(``xdd_d = xdd_d2s + xdd_s``; eq. 45 gives ``m_d xdd_d = -(c_d xd_d2s + k_d x_d2s)``),
with ``m_frame`` = 250.0 lbm (seed section 5.1, ``FRAME_MASS_KG``).

The combined linear system (state ``[q, x_d2s, xd_d2s]``, input ``u``) is
discretised exactly with a zero-order hold at ``fs_hz`` (augmented matrix
exponential), so one sample is one small matrix-vector product.  Timing
convention (shared with rths_compensator): ``write(u_k)`` holds ``u_k`` for one
sample and advances the plant to the end of that sample; ``read()`` returns the
measurement at that instant, labelled step ``k``.

Optional Coulomb friction on the moving mass, ``f_c = friction_n sign(xd_d2s)``
(regularised as ``friction_n tanh(xd_d2s / friction_v_m_s)``), adds
``-f_c / m_d`` to ``xdd_d2s``; then each sample is split into
``friction_substeps`` exact-ZOH sub-steps with the friction force held per
sub-step.

Identified ARX actuator (``actuator_model`` = path to a plant.yaml of
rths_compensator.identification: ``y_k + a1 y_{k-1} + ... = b1 u_{k-d} + b2 u_{k-d-1} + ...``,
i.e. the project's d = 0 convention): the table displacement ``x_s`` is the
ARX output.  Between samples ``x_s`` is taken piecewise linear (first-order
hold), the DTM is discretised exactly in absolute coordinates for that input,
and the table acceleration is the backward second difference of ``x_s``
(an approximation: an ARX model carries no continuous acceleration).

DAQ: the specimen channels (table acceleration, DTM relative displacement and
velocity) pass identical 2nd-order Butterworth anti-alias filters at
``daq_filter_hz`` (continuous states in the same ZOH model), as a data
acquisition system would; identical filters keep eq. 47 between them, and
they remove the sample-synchronous acceleration ripple of the ZOH command
staircase that a raw sample of ``xdd_s`` would alias into the record.  The
actuator displacement and the force are not filtered (no extra loop delay).

A device specimen (``specimen: mr``, a magnetorheological damper between the table
and the reaction frame) is advanced by :mod:`.stroke_specimen`: its stroke is the table
displacement and the measured force is the device force (for ``mr`` the Bouc-Wen model
of Spencer et al. 1997 at the constant voltage ``mr_voltage_v``).

Hidden effects (the simulated lab as a test of the discrepancy workflow): bridge keys in
physical units that make the lab differ from its nominal model by one effect of the
library of :mod:`rths_discrepancy.effects` (:data:`HIDDEN_EFFECTS` maps each key to its
scenario and effect).  They are recorded with the other bridge parameters in the bag's
run information (the ground truth of a test); the workflow never reads them.  On the
mass on the table: ``specimen_damping_error_n_s_m`` (c_d + dc), ``specimen_stiffness_error_n_m``
(k_d + dk), ``specimen_mass_error_kg`` (m_d + dm), and the forces on the moving mass
``friction_n`` (above), ``specimen_cubic_stiffness_n_m3`` (k3 x^3) and ``specimen_backlash_m``
(``k_d (dz(x, b) - x)``, a clearance +-b before the spring engages), integrated with the
friction's sub-steps, and, outside the library (the control of a test that must end in
``unexplained``), ``specimen_quadratic_damping_n_s2_m2`` (c2 v|v|); on the sensors:
``rel_disp_bias_m`` (the DTM displacement sensor),
``force_offset_n`` (the load cells: their reading, the measured force the bridge returns to
the numerical substructure, is ``R + force_offset_n``; the same physical thing and sign as
the library's ``force_offset`` F_0, which eq. 45's force ``m_f xdd_s - R`` shows as ``-F_0``)
and ``displacement_bias_m`` (the actuator's displacement sensor); in the command path the
bridge's ``command_delay_steps``; ``specimen_velocity_saturation_m_s`` (a choked DTM valve:
the damping force ``c_d clip(xd, -v_sat, v_sat)``).  On the actuator, the library's loads on
the servo loop ``y = G (u - q)`` (seed eq. 3 with control-structure interaction;
``q`` [m] from the table's displacement y, velocity and acceleration, sub-stepped like the
friction): ``actuator_friction_m`` (d_c tanh(yd / friction_v_m_s)),
``actuator_velocity_load_s`` (tau_v yd), ``actuator_stiffness_load`` (kappa y),
``actuator_cubic_load_1_m2`` (k3 y^3), ``actuator_inertia_load_s2`` (mu ydd), and the two
operators the library writes on the actuator's output y, applied to what its displacement
sensor reads: ``actuator_backlash_m`` (a play of half-width b between the rod and the
sensor) and ``actuator_velocity_limit_m_s`` (the reading follows y at most v_max fast; the
table's own motion under the specimen stays the linear model's).  The library's specimen
``time_delay`` has no key: it delays eq. 45's derived force ``m_f xdd_s - R`` behind the
table acceleration, which no lag of one physical sensor produces (a load-cell lag delays
``R`` but not ``m_f xdd_s``); an actuator delay is the bridge's ``command_delay_steps``.

Sensors: Gaussian noise of standard deviation ``displacement_noise_m``,
``force_noise_n``, ``rel_disp_noise_m``, ``accel_noise_m_s2`` from a seeded
``numpy.random.Generator``; ADC quantisation with ``adc_bits`` over
``+-displacement_range_m``, ``+-force_range_n``, ``+-rel_disp_range_m``,
``+-accel_range_m_s2`` (0 bits = no quantisation).
"""

from dataclasses import dataclass, field, replace
import math

import numpy as np

from rths_common.params import LOOP_RATE_RANGE_HZ, renamed
from rths_common.timebase import same_rate
from rths_compensator.plants import actuator_poles
from rths_numerical.dtm import DTMParameters
from rths_numerical.specimens import DEFAULT_SPECIMEN, SPECIMENS, specimen_params

from .backend import Backend
from .channels import CHANNELS, zoh
from .silva2020 import BRIDGE_PARAMS, channel_model
from .stroke_specimen import StrokeTableSpecimen


def _quantise(x, bits: int, full_range: float):
    """Round ``x`` to an ``bits``-bit ADC over ``+-full_range`` (clipped at the rails)."""
    if bits <= 0 or full_range <= 0:
        return x
    lsb = 2.0 * full_range / 2 ** bits
    return np.clip(np.round(np.asarray(x) / lsb) * lsb, -full_range, full_range)


@dataclass
class PlantConfig:
    """Parameters of :class:`SimulatedPlant` (SI units; see :data:`SIM_PARAMS`)."""

    fs_hz: float = 1024.0
    actuator_model: str = '3pole'
    specimen: str = DEFAULT_SPECIMEN
    frame_mass_kg: float = float('nan')  # nan -> the specimen's frame mass
    displacement_noise_m: float = 0.0
    force_noise_n: float = 0.0
    rel_disp_noise_m: float = 0.0
    accel_noise_m_s2: float = 0.0
    adc_bits: int = 0
    displacement_range_m: float = 0.254
    force_range_n: float = 8000.0
    rel_disp_range_m: float = 0.254
    accel_range_m_s2: float = 100.0
    seed: int = 0
    friction_n: float = 0.0
    friction_v_m_s: float = 1e-3
    friction_substeps: int = 16
    daq_filter_hz: float = 200.0
    specimen_damping_error_n_s_m: float = 0.0
    specimen_stiffness_error_n_m: float = 0.0
    specimen_mass_error_kg: float = 0.0
    specimen_cubic_stiffness_n_m3: float = 0.0
    specimen_backlash_m: float = 0.0
    specimen_quadratic_damping_n_s2_m2: float = 0.0
    rel_disp_bias_m: float = 0.0
    force_offset_n: float = 0.0
    displacement_bias_m: float = 0.0
    specimen_velocity_saturation_m_s: float = 0.0
    actuator_friction_m: float = 0.0
    actuator_velocity_load_s: float = 0.0
    actuator_stiffness_load: float = 0.0
    actuator_cubic_load_1_m2: float = 0.0
    actuator_inertia_load_s2: float = 0.0
    actuator_backlash_m: float = 0.0
    actuator_velocity_limit_m_s: float = 0.0
    specimen_settings: dict = field(default_factory=dict)   # the specimen's own parameters


#: Simulated-backend parameters: key -> (type, default, unit/meaning).
SIM_PARAMS = {
    'fs_hz': (float, 1024.0, '[Hz] loop sampling frequency (seed: 1024 Hz)'),
    'actuator_model': (str, '3pole', "'3pole' | '4pole' (Table 1) | 'silva2020' (benchmark "
                       'plant with its specimen, see silva2020.py) | path to an ARX plant.yaml'),
    'specimen': (str, DEFAULT_SPECIMEN, 'the specimen on the table '
                 '(rths_numerical.specimens.SPECIMENS)'),
    'frame_mass_kg': (float, float('nan'),
                      "[kg] mass the load cells carry with the table (default: the specimen's; "
                      'the DTM frame 250.0 lbm = 113.4 kg)'),
    'displacement_noise_m': (float, 0.0, '[m] std of actuator displacement sensor noise'),
    'force_noise_n': (float, 0.0, '[N] std of load-cell force noise'),
    'rel_disp_noise_m': (float, 0.0, '[m] std of DTM relative-displacement (LVDT) noise'),
    'accel_noise_m_s2': (float, 0.0, '[m/s^2] std of table accelerometer noise'),
    'adc_bits': (int, 0, '[-] ADC resolution; 0 = no quantisation'),
    'displacement_range_m': (float, 0.254, '[m] ADC full scale +- of displacement'),
    'force_range_n': (float, 8000.0, '[N] ADC full scale +- of force'),
    'rel_disp_range_m': (float, 0.254, '[m] ADC full scale +- of DTM relative displacement'),
    'accel_range_m_s2': (float, 100.0, '[m/s^2] ADC full scale +- of table acceleration'),
    'seed': (int, 0, '[-] seed of the noise generator (reproducible runs)'),
    'friction_n': (float, 0.0, '[N] Coulomb friction force on the DTM moving mass; 0 = linear'),
    'friction_v_m_s': (float, 1e-3, '[m/s] velocity scale of the tanh-regularised friction sign'),
    'friction_substeps': (int, 16, '[-] sub-steps per sample when friction_n > 0'),
    'daq_filter_hz': (float, 200.0, '[Hz] cut-off of the 2nd-order Butterworth anti-alias '
                      'filter of the specimen channels (table_accel, rel_disp, rel_vel); 0 = off'),
    'specimen_damping_error_n_s_m': (float, 0.0, '[N s/m] hidden: damping added to the '
                                     "DTM's c_d"),
    'specimen_stiffness_error_n_m': (float, 0.0, "[N/m] hidden: stiffness added to the DTM's k_d"),
    'specimen_mass_error_kg': (float, 0.0, "[kg] hidden: mass added to the DTM's m_d"),
    'specimen_cubic_stiffness_n_m3': (float, 0.0, '[N/m^3] hidden: cubic spring k3 x^3 on the '
                                      'DTM moving mass'),
    'specimen_backlash_m': (float, 0.0, '[m] hidden: clearance +-b before the DTM spring '
                            'engages'),
    'specimen_quadratic_damping_n_s2_m2': (float, 0.0, '[N s^2/m^2] hidden, outside the effect '
                                           'library: quadratic damping c2 v|v| on the DTM '
                                           'moving mass'),
    'rel_disp_bias_m': (float, 0.0, '[m] hidden: offset of the DTM relative-displacement sensor'),
    'force_offset_n': (float, 0.0, '[N] hidden: offset of the load-cell reading (the measured '
                       'force reads R + force_offset_n): the force_offset F_0 of the discrepancy '
                       'library, same sign'),
    'displacement_bias_m': (float, 0.0, "[m] hidden: offset of the actuator's displacement "
                            'sensor'),
    'specimen_velocity_saturation_m_s': (float, 0.0, '[m/s] hidden: the DTM damping force '
                                         'saturates above this relative velocity (a choked '
                                         'valve); 0 = off'),
    'actuator_friction_m': (float, 0.0, '[m] hidden: Coulomb load on the servo loop, '
                            'displacement-equivalent d_c tanh(yd / friction_v_m_s)'),
    'actuator_velocity_load_s': (float, 0.0, '[s] hidden: velocity load tau_v yd on the servo '
                                 'loop'),
    'actuator_stiffness_load': (float, 0.0, '[-] hidden: stiffness load (gain error) kappa y '
                                'on the servo loop'),
    'actuator_cubic_load_1_m2': (float, 0.0, '[1/m^2] hidden: cubic stiffness load k3 y^3 on '
                                 'the servo loop'),
    'actuator_inertia_load_s2': (float, 0.0, '[s^2] hidden: inertia load mu ydd on the servo '
                                 'loop'),
    'actuator_backlash_m': (float, 0.0, "[m] hidden: play of half-width b between the rod and "
                            "the actuator's displacement sensor; 0 = off"),
    'actuator_velocity_limit_m_s': (float, 0.0, "[m/s] hidden: the actuator's displacement "
                                    'reading follows y at most this fast (servo-valve flow '
                                    'limit, as the library writes it); 0 = off'),
    **specimen_params()[0],
}

#: Hidden-effect keys of :data:`SIM_PARAMS` -> (scenario, effect of rths_discrepancy.effects).
#: The bridge's ``command_delay_steps`` (D steps) is the actuator's ``time_delay`` D / fs_hz.
HIDDEN_EFFECTS = {
    'friction_n': ('specimen', 'coulomb_friction'),
    'specimen_damping_error_n_s_m': ('specimen', 'viscous_damping_error'),
    'specimen_stiffness_error_n_m': ('specimen', 'stiffness_error'),
    'specimen_mass_error_kg': ('specimen', 'mass_error'),
    'specimen_cubic_stiffness_n_m3': ('specimen', 'cubic_stiffness'),
    'specimen_backlash_m': ('specimen', 'backlash'),
    'rel_disp_bias_m': ('specimen', 'sensor_bias'),
    'force_offset_n': ('specimen', 'force_offset'),
    'displacement_bias_m': ('actuator', 'sensor_bias'),
    'command_delay_steps': ('actuator', 'time_delay'),
    'specimen_velocity_saturation_m_s': ('specimen', 'velocity_saturation'),
    'actuator_friction_m': ('actuator', 'coulomb_friction'),
    'actuator_velocity_load_s': ('actuator', 'viscous_damping_error'),
    'actuator_stiffness_load': ('actuator', 'stiffness_error'),
    'actuator_cubic_load_1_m2': ('actuator', 'cubic_stiffness'),
    'actuator_inertia_load_s2': ('actuator', 'mass_error'),
    'actuator_backlash_m': ('actuator', 'backlash'),
    'actuator_velocity_limit_m_s': ('actuator', 'velocity_saturation'),
    'specimen_quadratic_damping_n_s2_m2': ('specimen', None),   # outside the library
}
#: The actuator's loads on its servo loop (sub-stepped: ``q`` from the table's state).
ACTUATOR_LOADS = ('actuator_friction_m', 'actuator_velocity_load_s', 'actuator_stiffness_load',
                  'actuator_cubic_load_1_m2', 'actuator_inertia_load_s2')
#: Ranges of the rates, counts and specimen settings of :data:`SIM_PARAMS` (inclusive).
SIM_RANGES = {
    'fs_hz': LOOP_RATE_RANGE_HZ,
    'adc_bits': (0, 32),
    'friction_n': (0.0, 1.0e6),
    'friction_substeps': (1, 4096),
    'daq_filter_hz': (0.0, 100_000.0),
    'specimen_damping_error_n_s_m': (-1.0e5, 1.0e5),
    'specimen_stiffness_error_n_m': (-1.0e7, 1.0e7),
    'specimen_mass_error_kg': (-1.0e4, 1.0e4),
    'specimen_cubic_stiffness_n_m3': (-1.0e13, 1.0e13),
    'specimen_backlash_m': (0.0, 0.1),
    'specimen_quadratic_damping_n_s2_m2': (-1.0e7, 1.0e7),
    'rel_disp_bias_m': (-0.254, 0.254),
    'force_offset_n': (-1.0e5, 1.0e5),
    'displacement_bias_m': (-0.254, 0.254),
    'specimen_velocity_saturation_m_s': (0.0, 100.0),
    'actuator_friction_m': (0.0, 0.1),
    'actuator_velocity_load_s': (-1.0, 1.0),
    'actuator_stiffness_load': (-0.9, 10.0),
    'actuator_cubic_load_1_m2': (-1.0e9, 1.0e9),
    'actuator_inertia_load_s2': (-1.0, 1.0),
    'actuator_backlash_m': (0.0, 0.1),
    'actuator_velocity_limit_m_s': (0.0, 100.0),
    **specimen_params()[1],
}
#: Allowed values of the plant's parameters that name a choice.
SIM_CHOICES = {'specimen': SPECIMENS.names()}

#: Specimen instrumentation channels that pass the DAQ anti-alias filter.
DAQ_FILTERED = ('table_accel', 'rel_disp', 'rel_vel')


def plant_config(params: dict) -> PlantConfig:
    """Build a :class:`PlantConfig` from flat parameters, validating each key (ValueError).

    The former key ``dtm`` is accepted for ``specimen`` with a one-line note.
    """
    where = "parameter 'dtm' (now 'specimen')" if 'dtm' in params else "parameter 'specimen'"
    params = renamed(params, 'dtm', 'specimen', 'bridge parameters')
    entry = SPECIMENS.entry(params.get('specimen', DEFAULT_SPECIMEN), where)
    own = set(specimen_params()[0])
    values = {'specimen_settings': entry.settings(params)}
    for key, (typ, default, meaning) in SIM_PARAMS.items():
        if key in own:
            continue
        raw = params.get(key, default)
        if typ is str and not isinstance(raw, str):   # str(None) would be the path 'None'
            raise ValueError(f'parameter {key!r} = {raw!r} is not text; set it to {meaning}')
        try:
            val = typ(raw)
        except (TypeError, ValueError):
            raise ValueError(f'parameter {key!r} = {raw!r} is not a {typ.__name__}; '
                             f'set it to {meaning}') from None
        values[key] = val
    cfg = PlantConfig(**values)
    if not (math.isfinite(cfg.fs_hz) and cfg.fs_hz > 0):
        raise ValueError(f"parameter 'fs_hz' = {cfg.fs_hz} must be a positive number of Hz "
                         '(e.g. 1024)')
    for key in ('daq_filter_hz', 'displacement_noise_m', 'force_noise_n', 'rel_disp_noise_m',
                'accel_noise_m_s2',
                'displacement_range_m', 'force_range_n', 'rel_disp_range_m', 'accel_range_m_s2',
                'friction_n', 'specimen_backlash_m', 'specimen_velocity_saturation_m_s',
                'actuator_friction_m', 'actuator_backlash_m', 'actuator_velocity_limit_m_s'):
        if not (getattr(cfg, key) >= 0 and math.isfinite(getattr(cfg, key))):
            raise ValueError(f'parameter {key!r} = {getattr(cfg, key)} must be finite and >= 0')
    if not 0 <= cfg.adc_bits <= 32:
        raise ValueError(f"parameter 'adc_bits' = {cfg.adc_bits} must be 0 (off) .. 32")
    if cfg.friction_substeps < 1 or not cfg.friction_v_m_s > 0:
        raise ValueError("parameters 'friction_substeps' must be >= 1 and 'friction_v_m_s' > 0")
    for key in ('specimen_damping_error_n_s_m', 'specimen_stiffness_error_n_m',
                'specimen_mass_error_kg', 'specimen_cubic_stiffness_n_m3', 'rel_disp_bias_m',
                'force_offset_n', 'displacement_bias_m', 'specimen_quadratic_damping_n_s2_m2',
                'actuator_velocity_load_s', 'actuator_stiffness_load', 'actuator_cubic_load_1_m2',
                'actuator_inertia_load_s2'):
        if not math.isfinite(getattr(cfg, key)):
            raise ValueError(f'parameter {key!r} = {getattr(cfg, key)} must be finite')
    if not (math.isnan(cfg.frame_mass_kg) or cfg.frame_mass_kg >= 0):
        raise ValueError(f"parameter 'frame_mass_kg' = {cfg.frame_mass_kg} must be >= 0")
    return cfg


#: Plant parameters that :meth:`SimulatedPlant.retune` scales during a run (1.0 = as built):
#: the actuator's DC gain, all its poles (bandwidth), its complex pole pairs only (the
#: oil-column/specimen mode that control-structure interaction moves) and the DTM's k_d.
RETUNE_KEYS = ('actuator_gain', 'actuator_bandwidth', 'actuator_mode_frequency',
               'dtm_stiffness')


def _actuator_ss(kind: str, scales: dict = None):
    """Return the controllable state space (A, B, C) of a Table 1 actuator model, retuned."""
    try:
        poles = actuator_poles(kind)
    except ValueError as err:
        raise ValueError(f"parameter 'actuator_model': {err}, or a path to an ARX plant.yaml") \
            from None
    scales = scales or {}
    poles = poles * scales.get('actuator_bandwidth', 1.0)
    poles = np.where(poles.imag != 0, poles * scales.get('actuator_mode_frequency', 1.0), poles)
    den = np.real(np.poly(poles))
    num = np.array([np.real(np.prod(-poles)) * scales.get('actuator_gain', 1.0)])
    # lazy: start-up cost: SciPy (~1.5 s) for every `rths` command (the CLI lists this)
    from scipy.signal import tf2ss

    a, b, c, d = tf2ss(num, den)
    if np.any(np.abs(d) > 0) or abs((c @ b).item()) > 1e-9 * np.abs(c).max():
        raise ValueError(f'actuator model {kind!r} must have relative degree >= 2')
    return a, b, c


class SimulatedPlant:
    """Actuator + shake table + DTM, advanced one sample per :meth:`step`.

    Use :meth:`step` in a loop, or :meth:`simulate` for a whole command record.
    """

    #: Parameters of the 'silva2020' plant (None: nominal; see :func:`silva2020_plant`)
    silva2020_params = None

    def __init__(self, config: PlantConfig = None, **params):
        """Build from a :class:`PlantConfig` or flat parameters (see :data:`SIM_PARAMS`)."""
        self.config = config if config is not None else plant_config(params)
        cfg = self.config
        self.dt = 1.0 / cfg.fs_hz
        self.specimen = SPECIMENS.entry(cfg.specimen, "parameter 'specimen'")
        # the mass on the table (eq. 46), or None
        self.dtm = self.specimen.mass_on_table(cfg.specimen_settings)
        self.frame_mass = (self.specimen.frame_mass(cfg.specimen_settings)
                           if math.isnan(cfg.frame_mass_kg) else cfg.frame_mass_kg)
        self.arx = None
        self._scales = dict.fromkeys(RETUNE_KEYS, 1.0)
        self._noiseless = (cfg.adc_bits <= 0 and cfg.displacement_noise_m <= 0
                           and cfg.force_noise_n <= 0 and cfg.rel_disp_noise_m <= 0
                           and cfg.accel_noise_m_s2 <= 0)
        if cfg.actuator_model in ('3pole', '4pole'):
            self._build_continuous(cfg.actuator_model)
        elif cfg.actuator_model == 'silva2020':
            self._build_silva2020()
        else:
            self._build_arx(cfg.actuator_model)
        self._check_hidden()
        self.mr = None   # a device specimen (between the table and the ground), if any
        device, substeps = self.specimen.make_device(cfg.specimen_settings)
        if device is not None:
            self.mr = StrokeTableSpecimen(self, device, substeps, cfg.specimen)
        self.reset()

    # ----------------------------------------------------------------- building
    def _check_hidden(self):
        """Refuse a hidden effect on the moving mass this plant cannot simulate (never drop it)."""
        cfg = self.config
        on_mass = [k for k in ('friction_n', 'specimen_damping_error_n_s_m',
                               'specimen_stiffness_error_n_m', 'specimen_mass_error_kg',
                               'specimen_cubic_stiffness_n_m3', 'specimen_backlash_m',
                               'specimen_quadratic_damping_n_s2_m2', 'rel_disp_bias_m',
                               'specimen_velocity_saturation_m_s')
                   if getattr(cfg, k)]
        if on_mass and self.dtm is None:
            raise ValueError(f"parameter(s) {', '.join(on_mass)}: specimen {cfg.specimen} has "
                             'no mass on the table; set them to 0')
        stepped = [k for k in ('friction_n', 'specimen_cubic_stiffness_n_m3',
                               'specimen_backlash_m', 'specimen_quadratic_damping_n_s2_m2',
                               'specimen_velocity_saturation_m_s', *ACTUATOR_LOADS,
                               'actuator_backlash_m', 'actuator_velocity_limit_m_s')
                   if getattr(cfg, k)]
        if stepped and cfg.actuator_model not in ('3pole', '4pole'):
            raise ValueError(f"parameter(s) {', '.join(stepped)} need the continuous actuator "
                             "model (actuator_model '3pole' or '4pole'), not "
                             f"{cfg.actuator_model!r}; set them to 0")
        if stepped and self.specimen.make_device(cfg.specimen_settings)[0] is not None:
            raise ValueError(f"parameter(s) {', '.join(stepped)}: not simulated with the device "
                             f'specimen {cfg.specimen}; set them to 0')

    def _table_mass(self) -> DTMParameters:
        """Return the mass on the table as built and retuned (a massless placeholder if none)."""
        if self.dtm is None:
            return DTMParameters(1.0, 0.0, 0.0)
        cfg = self.config
        mass = replace(self.dtm, m_d=self.dtm.m_d + cfg.specimen_mass_error_kg,
                       c_d=self.dtm.c_d + cfg.specimen_damping_error_n_s_m,
                       k_d=self.dtm.k_d + cfg.specimen_stiffness_error_n_m)
        if not (mass.m_d > 0 and mass.c_d >= 0 and mass.k_d > 0):
            raise ValueError('the hidden specimen errors leave m_d <= 0, c_d < 0 or k_d <= 0 '
                             f'(m_d {mass.m_d:g} kg, c_d {mass.c_d:g} N s/m, k_d {mass.k_d:g} '
                             'N/m); use smaller errors')
        return replace(mass, k_d=mass.k_d * self._scales['dtm_stiffness'])

    def _dtm_cmk(self):
        """Return ``(m_d, c_d, k_d)`` of the mass on the table, retuned."""
        mass = self._table_mass()
        return mass.m_d, mass.c_d, mass.k_d

    def _build_continuous(self, kind: str):
        aa, ba, ca = _actuator_ss(kind, self._scales)
        n = aa.shape[0]
        mass = self._table_mass()
        a_m, b_m = mass.state_space()  # eq. 46: inputs table acceleration, friction force
        c_acc = ca @ aa @ aa           # xdd_s = C A^2 q + C A B u
        d_acc = (ca @ aa @ ba).item()
        a = np.zeros((n + 2, n + 2))
        a[:n, :n] = aa
        a[n:, n:] = a_m
        a[n + 1, :n] = b_m[1, 0] * c_acc.ravel()
        b = np.zeros((n + 2, 2))       # inputs: command u, friction force f_c [N]
        b[:n, 0] = ba.ravel()
        b[n + 1, 0] = b_m[1, 0] * d_acc
        b[n + 1, 1] = b_m[1, 1]
        c_d, k_d = mass.c_d, mass.k_d
        if self.dtm is None:       # bare table: DTM states stay at zero
            a[n:, :] = 0.0
            b[n:, :] = 0.0
        # outputs: table disp, vel, accel, rel disp, rel vel, force (CHANNELS order)
        c = np.zeros((6, n + 2))
        d = np.zeros((6, 2))
        c[0, :n] = ca.ravel()
        c[1, :n] = (ca @ aa).ravel()
        c[2, :n] = c_acc.ravel()
        d[2, 0] = d_acc
        c[3, n] = 1.0
        c[4, n + 1] = 1.0
        c[5] = self.frame_mass * c[2]
        c[5, n] -= k_d
        c[5, n + 1] -= c_d
        d[5, 0] = self.frame_mass * d_acc
        d[5, 1] = -1.0 if self.dtm is not None else 0.0
        self._i_rel_vel = n + 1
        # the table's displacement, velocity and acceleration before the DAQ filter (the
        # actuator's loads on its servo loop read them), padded to the filtered state
        a, b, c_f, d_f = self._add_daq_filter(a, b, c, d)
        self._c_table = np.zeros((3, a.shape[0]))
        self._c_table[:, :n + 2] = c[:3]
        self._d_table = d[:3, 0].copy()
        self._set_linear(a, b, c_f, d_f)

    def _build_silva2020(self):
        """Build the benchmark plant of :mod:`.silva2020` (it carries its own SDOF specimen)."""
        self.dtm, self.frame_mass = None, 0.0
        self._set_linear(*channel_model(self.silva2020_params))

    def _set_linear(self, a, b, c, d):
        """Keep the continuous model (inputs [u, f_c], CHANNELS outputs) and its ZOH form."""
        self.a_c, self.b_c, self.c, self.d = a, b, c, d
        self.n_states = a.shape[0]
        self._ad, self._bd = zoh(a, b, self.dt)
        # one-sample fast path of step(): contiguous command columns, preallocated buffers
        self._bd_u = np.ascontiguousarray(self._bd[:, 0])
        self._d_u = np.ascontiguousarray(self.d[:, 0])
        self._x_buf = np.zeros(self.n_states)
        self._x_tmp = np.zeros(self.n_states)
        self._y_buf = np.zeros(self.c.shape[0])
        self._y_tmp = np.zeros(self.c.shape[0])
        if self._nonlinear:
            h = self.dt / self.config.friction_substeps
            self._ad_h, self._bd_h = zoh(a, b, h)

    def _add_daq_filter(self, a, b, c, d):
        """Append 2nd-order Butterworth anti-alias filters on the specimen channels."""
        fc = self.config.daq_filter_hz
        if fc <= 0:
            return a, b, c, d
        w = 2 * np.pi * fc
        rows = [CHANNELS.index(k) for k in DAQ_FILTERED]
        n0 = a.shape[0]
        n = n0 + 2 * len(rows)
        a2 = np.zeros((n, n))
        a2[:n0, :n0] = a
        b2 = np.zeros((n, b.shape[1]))
        b2[:n0] = b
        c2 = np.zeros((c.shape[0], n))
        c2[:, :n0] = c
        d2 = d.copy()
        for j, r in enumerate(rows):
            i = n0 + 2 * j            # z' = v, v' = w^2 (y_in - z) - sqrt(2) w v
            a2[i, i + 1] = 1.0
            a2[i + 1, :n0] = w * w * c[r]
            a2[i + 1, i] = -w * w
            a2[i + 1, i + 1] = -np.sqrt(2) * w
            b2[i + 1] = w * w * d[r]
            c2[r] = 0.0
            c2[r, i] = 1.0
            d2[r] = 0.0
        return a2, b2, c2, d2

    def _build_arx(self, path: str):
        try:
            # lazy: optional: tried here, refused with a clear message when missing
            from rths_compensator.identification import load_plant
        except ImportError:
            raise ValueError(f"parameter 'actuator_model' = {path!r}: loading an ARX plant.yaml "
                             'needs rths_compensator.identification, which is not available; '
                             "use '3pole' or '4pole'") from None
        model = load_plant(path)
        if model.loads:   # an updated model's non-linear loads: the lab cannot drop them
            raise ValueError(f"parameter 'actuator_model' = {path!r} holds the loads "
                             f'{", ".join(model.loads)} (an updated model of rths '
                             'discrepancy): the ARX lab has no servo-loop load; hide a load '
                             'with the actuator_* keys (actuator_friction_m, '
                             'actuator_cubic_load_1_m2) on the 3pole/4pole lab instead')
        if not same_rate(model.fs_hz, self.config.fs_hz):
            raise ValueError(f'ARX plant {path}: fs_hz {model.fs_hz} differs from the loop '
                             f"fs_hz {self.config.fs_hz}; set 'fs_hz' to {model.fs_hz}")
        self.arx = model
        a = np.asarray(model.a, float)
        b = np.concatenate([np.zeros(int(model.d)), np.asarray(model.b, float)])
        self._arx_a, self._arx_b = a / a[0], b / a[0]
        a_m, _ = self._table_mass().state_space()
        # absolute DTM coordinates [x_d, v_d, x_s, slope], x_s linear within a sample:
        # eq. 46 in x_d2s = x_d - x_s (its table-acceleration input cancels)
        a4 = np.zeros((4, 4))
        a4[0, 1] = 1.0
        a4[1] = [a_m[1, 0], a_m[1, 1], -a_m[1, 0], -a_m[1, 1]]
        a4[2, 3] = 1.0
        # lazy: start-up cost: scipy.linalg (~0.4 s) for every `rths` command (the CLI lists this)
        from scipy.linalg import expm

        self._arx_dtm = expm(a4 * self.dt)

    def retune(self, **scales):
        """Scale plant parameters (:data:`RETUNE_KEYS`, factors of the built values) from now on.

        The continuous model is re-discretised and the physical state carried over: the DTM
        and DAQ states unchanged, the actuator state mapped so that the table displacement
        and its derivatives (up to the model order - 1) stay continuous.  Continuous
        actuator models only (a damage step or a drift during a test).
        """
        if self.config.actuator_model not in ('3pole', '4pole') or self.mr is not None:
            raise ValueError('retune needs a continuous Table 1 actuator model (3pole, 4pole) '
                             f'and a linear specimen (not specimen: {self.config.specimen})')
        for key, value in scales.items():
            if key not in RETUNE_KEYS:
                raise ValueError(f'retune: unknown parameter {key!r}; use {RETUNE_KEYS}')
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f'retune: {key} = {value} must be a finite factor > 0')
        obs_old = self._actuator_observability()
        phys = obs_old @ self.x[:obs_old.shape[0]]
        x = self.x.copy()
        self._scales.update(scales)
        self._build_continuous(self.config.actuator_model)
        obs_new = self._actuator_observability()
        x[:obs_new.shape[0]] = np.linalg.solve(obs_new, phys)
        self.x = x

    def _actuator_observability(self):
        """Rows ``C A^i`` (i < n) of the actuator block: its state -> x_s and derivatives."""
        n = self.n_states - 2 - 2 * (len(DAQ_FILTERED) if self.config.daq_filter_hz > 0 else 0)
        a, c = self.a_c[:n, :n], self.c[0, :n]
        rows = [c]
        for _ in range(n - 1):
            rows.append(rows[-1] @ a)
        return np.array(rows)

    # ----------------------------------------------------------------- running
    def reset(self):
        """Put the plant at rest at zero and re-seed the noise generator."""
        self.rng = np.random.default_rng(self.config.seed)
        self.k = -1
        if self.arx is None:
            self.x = np.zeros(self.n_states)
        else:
            self._u_hist = np.zeros(len(self._arx_b))
            self._y_hist = np.zeros(len(self._arx_a) - 1)
            self._z = np.zeros(2)
            self._xs, self._slope = 0.0, 0.0
        if getattr(self, 'mr', None) is not None:   # (reset() runs before mr is set)
            self.mr.reset()
        self.true = dict.fromkeys(CHANNELS, 0.0)
        self._rate_out = self._play_out = 0.0
        self._rod_read = (self.config.actuator_backlash_m > 0
                          or self.config.actuator_velocity_limit_m_s > 0)
        self._stepped_nonlinear = None      # step()'s _nonlinear, taken at its first call

    @property
    def _nonlinear(self) -> bool:
        """Return True if a force on the moving mass needs the sub-stepped integration."""
        cfg = self.config
        on_mass = self.dtm is not None and (cfg.friction_n > 0 or cfg.specimen_backlash_m > 0
                                            or cfg.specimen_cubic_stiffness_n_m3 != 0
                                            or cfg.specimen_quadratic_damping_n_s2_m2 != 0
                                            or cfg.specimen_velocity_saturation_m_s > 0)
        return on_mass or self._loaded

    @property
    def _loaded(self) -> bool:
        """Return True if a hidden load acts on the actuator's servo loop."""
        return any(getattr(self.config, k) for k in ACTUATOR_LOADS)

    def _load(self, x, u: float) -> float:
        """Return the displacement-equivalent load q [m] on the servo loop: ``y = G (u - q)``."""
        cfg = self.config
        y, v, a = (self._c_table @ x + self._d_table * u).tolist()
        q = (cfg.actuator_velocity_load_s * v + cfg.actuator_stiffness_load * y
             + cfg.actuator_cubic_load_1_m2 * y * y * y + cfg.actuator_inertia_load_s2 * a)
        if cfg.actuator_friction_m:
            q += cfg.actuator_friction_m * math.tanh(v / cfg.friction_v_m_s)
        return q

    def _read_rod(self, y: float) -> float:
        """Return the actuator's displacement reading of the rod at ``y`` (rate limit, play)."""
        cfg = self.config
        out = y
        if cfg.actuator_velocity_limit_m_s > 0:
            step = cfg.actuator_velocity_limit_m_s * self.dt
            last = self._rate_out
            out = last + min(max(out - last, -step), step)
            self._rate_out = out
        if cfg.actuator_backlash_m > 0:
            b, last = cfg.actuator_backlash_m, self._play_out
            out = min(max(last, out - b), out + b)
            self._play_out = out
        return out

    def _friction(self, rel_disp: float, rel_vel: float) -> float:
        """Return the force [N] on the moving mass: friction and the hidden nonlinear forces."""
        cfg = self.config
        f = cfg.friction_n * math.tanh(rel_vel / cfg.friction_v_m_s)
        f += cfg.specimen_cubic_stiffness_n_m3 * rel_disp ** 3
        f += cfg.specimen_quadratic_damping_n_s2_m2 * rel_vel * abs(rel_vel)
        if cfg.specimen_backlash_m > 0:
            dz = math.copysign(max(abs(rel_disp) - cfg.specimen_backlash_m, 0.0), rel_disp)
            f += self._table_mass().k_d * (dz - rel_disp)
        if cfg.specimen_velocity_saturation_m_s > 0:
            vs = cfg.specimen_velocity_saturation_m_s
            f += self._table_mass().c_d * (min(max(rel_vel, -vs), vs) - rel_vel)
        return f

    def step(self, command: float) -> dict:
        """Hold ``command`` [m] for one sample; return the true channels at its end."""
        u = float(command)
        if self.mr is not None:
            return self.mr.step(u)
        if self.arx is not None:
            return self._step_arx(u)
        nonlinear = self._stepped_nonlinear
        if nonlinear is None:     # the settings are fixed once built: looked at once a run
            nonlinear = self._stepped_nonlinear = self._nonlinear
        if nonlinear:
            fc = ue = 0.0
            loaded = self._loaded
            for _ in range(self.config.friction_substeps):
                fc = self._friction(self.x[self._i_rel_vel - 1], self.x[self._i_rel_vel])
                ue = u - self._load(self.x, u) if loaded else u
                self.x = self._ad_h @ self.x + self._bd_h @ np.array([ue, fc])
            fc = self._friction(self.x[self._i_rel_vel - 1], self.x[self._i_rel_vel])
            y = self.c @ self.x + self.d @ np.array([ue if loaded else u, fc])
        else:
            # x' = Ad x + Bd u, y = C x' + D u: the same operations as
            # ``self._ad @ self.x + self._bd[:, 0] * u``, into preallocated buffers
            # (bit-identical results, no per-step allocation but the two buffers swap)
            x_new, tmp = self._x_buf, self._x_tmp
            np.dot(self._ad, self.x, out=x_new)
            np.multiply(self._bd_u, u, out=tmp)
            np.add(x_new, tmp, out=x_new)
            self._x_buf, self.x = self.x, x_new
            y, tmp = self._y_buf, self._y_tmp
            np.dot(self.c, x_new, out=y)
            np.multiply(self._d_u, u, out=tmp)
            np.add(y, tmp, out=y)
        self.k += 1
        self.true = dict(zip(CHANNELS, y.tolist(), strict=True))
        if self._rod_read:
            self.true['table_disp'] = self._read_rod(self.true['table_disp'])
        return self.true

    def _step_arx(self, u: float) -> dict:
        self._u_hist = np.roll(self._u_hist, 1)
        self._u_hist[0] = u
        xs_new = float(self._arx_b @ self._u_hist - self._arx_a[1:] @ self._y_hist)
        if len(self._y_hist):
            self._y_hist = np.roll(self._y_hist, 1)
            self._y_hist[0] = xs_new
        slope = (xs_new - self._xs) / self.dt
        w = self._arx_dtm @ np.array([self._z[0], self._z[1], self._xs, slope])
        self._z = w[:2]
        accel = (slope - self._slope) / self.dt
        self._xs, self._slope = xs_new, slope
        rel_disp = self._z[0] - xs_new if self.dtm is not None else 0.0
        rel_vel = self._z[1] - slope if self.dtm is not None else 0.0
        force = self.frame_mass * accel - self._table_mass().frame_force(rel_disp, rel_vel)
        self.k += 1
        values = (xs_new, slope, accel, rel_disp, rel_vel, force)
        self.true = dict(zip(CHANNELS, values, strict=True))
        return self.true

    def measure(self, true: dict = None) -> dict:
        """Sensor readings (noise + ADC) of the true channels (default: the latest)."""
        cfg = self.config
        t = self.true if true is None else true
        out = dict(t)
        for key, bias in (('rel_disp', cfg.rel_disp_bias_m), ('force', cfg.force_offset_n),
                          ('table_disp', cfg.displacement_bias_m)):
            if bias:
                out[key] = out[key] + bias
        if self._noiseless:
            return out      # no noise, no ADC: the true values (as floats for one sample)
        spec = (('table_disp', cfg.displacement_noise_m, cfg.displacement_range_m),
                ('force', cfg.force_noise_n, cfg.force_range_n),
                ('rel_disp', cfg.rel_disp_noise_m, cfg.rel_disp_range_m),
                ('table_accel', cfg.accel_noise_m_s2, cfg.accel_range_m_s2))
        for key, sigma, full in spec:
            val = np.asarray(out[key], float)
            if sigma > 0:
                val = val + sigma * self.rng.standard_normal(val.shape)
            out[key] = _quantise(val, cfg.adc_bits, full)
        return out

    def simulate(self, commands) -> dict:
        """Run a whole command record from the current state; return measured channel arrays.

        Equivalent to calling :meth:`step` per sample then measuring, but the
        linear case runs as one vectorised state-space filter.
        """
        u = np.asarray(commands, float).ravel()
        if self.arx is None and self.mr is None and not (self._nonlinear or self._rod_read):
            true = self._simulate_linear(u)
        else:
            rows = [self.step(ui) for ui in u]
            true = {key: np.array([r[key] for r in rows]) for key in CHANNELS}
        return self.measure(true)

    def _simulate_linear(self, u: np.ndarray) -> dict:
        """Exact ZOH response to a record: modal first-order IIR filters (C speed).

        With ``Ad = V diag(lam) V^-1`` and ``z = V^-1 x``, each mode obeys
        ``z_{k+1} = lam z_k + g u_k``, one complex ``lfilter`` call per mode.
        """
        if len(u) == 0:
            return {key: np.zeros(0) for key in CHANNELS}
        # lazy: start-up cost: scipy.signal (~1.5 s), as in _actuator_ss
        from scipy.signal import lfilter

        lam, vec = np.linalg.eig(self._ad)
        g = np.linalg.solve(vec, self._bd[:, 0].astype(complex))
        z0 = np.linalg.solve(vec, self.x.astype(complex))
        z_next = np.empty((len(u), len(lam)), complex)
        for i, li in enumerate(lam):
            z_next[:, i] = lfilter([g[i]], [1.0, -li], u, zi=[li * z0[i]])[0]
        x_next = np.real(z_next @ vec.T)
        ys = x_next @ self.c.T + np.outer(u, self.d[:, 0])
        self.x = x_next[-1].copy()
        self.k += len(u)
        true = {key: ys[:, i] for i, key in enumerate(CHANNELS)}
        self.true = {key: float(v[-1]) for key, v in true.items()}
        return true


def silva2020_plant(params=None, **config) -> SimulatedPlant:
    """Build the benchmark plant of :mod:`.silva2020` as a :class:`SimulatedPlant`.

    ``params`` is a :class:`.silva2020.Silva2020Params` (None: nominal); ``config``
    overrides :data:`.silva2020.BRIDGE_PARAMS` (e.g. ``seed``, or zero noise).
    """
    class Silva2020Plant(SimulatedPlant):
        silva2020_params = params

    return Silva2020Plant(**{**BRIDGE_PARAMS, **config})


class SimulatedBackend(Backend):
    """Backend over :class:`SimulatedPlant`; each ``write()`` advances exactly one sample."""

    summary = 'simulated plant: actuator + shake table + specimen (simulated.py)'
    params = SIM_PARAMS
    ranges = SIM_RANGES
    choices = SIM_CHOICES
    in_process = True

    def _configure(self, params: dict):
        self.plant = SimulatedPlant(plant_config(params))
        self.n_channels = 1
        self._last = None

    def _activate(self):
        self.plant.reset()
        self._last = None

    def _deactivate(self):
        """Nothing to stop: the plant advances only when written to."""

    def _write(self, command):
        self.plant.step(float(command[0]))
        self._last = self.plant.measure()

    def write_read_one(self, command: float):
        """Fast path of write + read + channels for one channel: a float in, floats out.

        Same checks and effect as :meth:`write` then :meth:`read` (the caller
        has checked that the backend is active); returns ``(displacement [m],
        force [N], channels)``, ``channels`` being this step's own dict.
        """
        if not math.isfinite(command):
            raise ValueError(f'refusing non-finite command {command}')
        self.step += 1
        self.plant.step(command)
        m = self._last = self.plant.measure()
        return float(m['table_disp']), float(m['force']), m

    def _read(self, wait_s=None):
        if self._last is None:
            raise RuntimeError('read() before the first write()')
        m = self._last
        return np.array([m['table_disp']]), np.array([m['force']])

    def channels(self) -> dict:
        """Latest measured channels: table_disp/vel/accel, rel_disp/vel, force."""
        return dict(self._last) if self._last else {}
