"""The numerical substructure the ROS node drives one loop step at a time (seed eq. 22-25).

Equation of the numerical substructure (seed eq. 25)::

    M^N u'' + C^N u' + K^N u + L (force_scale * R^E) = -M^N Gamma a_g + F s(t) + L P_I^E

``L`` places the interface entries (``interface_dofs``) into the full vector,
``R^E`` is the measured force [N] per interface DOF, ``force_scale`` the
number of identical specimens it represents (seed 6.2: one DTM in the lab
stands for five, so 5.0), ``F s(t)`` the model's optional external force
(``external_force`` of a model YAML file, :class:`.model.LinearModel`).

Lock-step cycle (one loop step k; see :meth:`NumericalSubstructure.advance`)::

    command_0 = sub.first_displacement()
    repeat: measured_k = lab(command_k); command_{k+1} = sub.advance(measured_k)

Physics note: the interface frame
---------------------------------
The project's measured force is ``R^E = m_frame * (table accel) + m_d * (moving
mass absolute accel)`` (load cells between table and specimen).  In the real
building, the DTM frame moves with the floor and the DTM's moving mass is
excited by the ABSOLUTE floor acceleration ``u_I'' + a_g``.

* ``interface_frame: relative`` (seed eq. 24 literally): the table follows
  the relative interface displacement ``u_I``; the ground term of the
  specimen is added numerically, ``P_I^E = -force_scale * specimen_mass_kg *
  a_g``.  For a rigid specimen this is exact, but the DTM's relative motion
  is then driven by ``u_I''`` only: the part of its response caused by
  ``a_g`` (the moving mass's own ``-m_d a_g`` load, a DOF of the experimental
  substructure E, eq. 21) is missing from the lab, and adding ``m_d a_g`` as
  if the mass were rigid does not restore it.
* ``interface_frame: absolute`` (DEFAULT): the table follows ``u_I + u_g``,
  so the specimen sees the true absolute floor motion, the measured force
  contains the whole specimen inertia including the ground term, and
  ``P_I^E = 0``.  This needs ``u_g`` consistent with ``a_g``: records are
  baseline-corrected (:func:`.ground_motion.baseline_correct`) and ``u_g`` is
  the trapezoidal double integral of the ``a_g`` used in the equation.

``test_substructure.py::test_absolute_frame_reproduces_reference`` runs both
against the whole-numerical reference (building + 5 DTMs + 5 frames, every
mass excited by the ground, :func:`.reference.simulate_reference`): the
absolute frame agrees to a fraction of a percent, the relative frame is off by
several percent (numbers in the test and the report), hence the default.

Parameters of :func:`make_substructure` (flat dict, as ROS parameters): the
registry :data:`PARAMS` (key -> default and meaning with unit).  Numbers 0 for
``duration_s``, ``harmonic_freq_hz``, ``building_mass_kg`` and an empty
``interface_dofs`` mean "default" (ROS parameters cannot be unset);
``use_sim_time`` and ``qos_overrides.*`` are ignored.
"""

import math
import os
from typing import Any

import numpy as np

from rths_common.params import (
    LOOP_RATE_RANGE_HZ,
    RATE_DIVISOR_RANGE,
    check_run_steps,
    node_schema,
)

from .building import BUILDING_MASS_KG, building_16dof
from .dtm import FRAME_MASS_KG, SEED_CONFIGURATION, TABLE4
from .excitation import EXCITATION_PARAMS, EXCITATION_RANGES, make_excitation
from .ground_motion import (
    G,
    GroundMotion,
    Processing,
    ground_motion,
    integrate,
    prepare,
    read_record,
)
from .integrators import INTEGRATORS, make_integrator
from .marths import MarthsSubstructure
from .model import LinearModel, load_model_yaml, sdof_model
from .multirate import MultiRateSubstructure
from .opensees_backend import (
    OpenSeesSubstructure,
    ScriptModel,
    linear_model_builder,
    script_builder,
)
from .silva2020 import model_by_name
from .stepping import BACKENDS, SteppedSubstructure

FRAMES = ('absolute', 'relative')
#: The ``model`` that runs the maRTHS benchmark's numerical substructure (:mod:`.marths`).
MARTHS_MODEL = 'marths'
#: Parameters every ROS node has; ignored here.
ROS_KEYS = ('use_sim_time', 'start_type_description_service')
#: The substructure's parameters: key -> (default, meaning [unit]); None = see the meaning.
PARAMS = {
    'backend': ('builtin', "'builtin' (this package's integrators) or 'opensees' (OpenSeesPy, "
                'optional: opensees_backend)'),
    'model': ('sdof', "'sdof', 'building2story' (16-DOF), 'silva2020_case1'..4 (benchmark, "
              "silva2020), 'marths' (the maRTHS benchmark's frame, two actuators' strokes "
              'and axial forces, marths.py) or a model YAML path; opensees also: an '
              'OpenSeesPy model script (.py path, or a name in config/models/, e.g. '
              "'frame-steel01')"),
    'integrator': (None, "builtin: 'cr' (default), 'kr_alpha', 'newmark', 'central_difference'; "
                   "opensees: 'central_difference' (default) or 'newmark'"),
    'rho_inf': (0.5, '[-] KR-alpha spectral radius at infinity, 0..1'),
    'fs_hz': (1024.0, '[Hz] loop rate (time step 1/fs_hz)'),
    'duration_s': (None, '[s] simulated time; 0 = whole record (10 s for blwn/harmonic/none)'),
    'record': ('harmonic', "'kobe', 'northridge', 'imperial_valley', 'none', 'blwn', "
               "'harmonic' or a record file (.AT2, .csv .txt .dat .tsv .asc)"),
    'record_format': ('', "record file format (empty: by its ending and content): at2, text, "
                      'series'),
    'record_units': ('', "acceleration unit of a record file whose header does not name it: g, "
                     "m/s^2, cm/s^2, gal (empty: the header's)"),
    'record_dt_s': (0.0, '[s] time step of a single-column record (0: from its time column)'),
    'record_resample': (True, 'resample the record to the loop rate (band-limited FFT); false: '
                        'its rate must be the loop rate'),
    'record_remove_mean': (True, "subtract the record's mean acceleration"),
    'record_baseline': (True, 'remove a cubic polynomial fitted to the ground displacement'),
    'scale': (0.1, '[-] record scale factor; BLWN/harmonic peak in g'),
    'harmonic_freq_hz': (None, "[Hz] frequency of the 'harmonic' ground acceleration "
                         '(0: the first mode)'),
    'blwn_band_hz': (10.0, '[Hz] BLWN band 0..f'),
    'seed': (0, '[-] random seed of BLWN'),
    'interface_dofs': (None, "[-] model DOF indices at the interface (empty: the model's)"),
    'force_scale': (None, '[-] specimens represented by the one in the lab (5 for '
                    'building2story, else 1)'),
    'interface_frame': ('absolute', "'absolute' or 'relative' (module docstring)"),
    'specimen_mass_kg': (FRAME_MASS_KG + TABLE4[SEED_CONFIGURATION].m_d,   # the seed's DTM
                         '[kg] mass of ONE specimen moving with the table, for P_I^E in the '
                         'relative frame'),
    'sdof_mass_kg': (1000.0, '[kg] SDOF mass'),
    'sdof_freq_hz': (2.81, '[Hz] SDOF natural frequency'),
    'sdof_zeta': (0.042, '[-] SDOF damping ratio'),
    'building_mass_kg': (None, "[kg] total mass of 'building2story' (0: 62 706 kg)"),
    'rate_divisor': (1, '[-] integrate the substructure at fs_hz / rate_divisor and '
                     'interpolate its interface displacement to every loop step '
                     '(multirate.py); 1: every loop step'),
}
#: Ranges of the rates, durations, gains and model settings of :data:`PARAMS` (inclusive).
RANGES = {
    'rho_inf': (0.0, 1.0),
    'fs_hz': LOOP_RATE_RANGE_HZ,
    'duration_s': (0.0, 1.0e6),
    'scale': (0.0, 1000.0),
    'record_dt_s': (0.0, 1000.0),
    'harmonic_freq_hz': (0.0, 100_000.0),
    'blwn_band_hz': (0.0, 100_000.0),
    'force_scale': (0.0, 1.0e6),
    'specimen_mass_kg': (0.0, 1.0e9),
    'sdof_mass_kg': (0.0, 1.0e12),
    'sdof_freq_hz': (0.0, 100_000.0),
    'sdof_zeta': (0.0, 10.0),
    'building_mass_kg': (0.0, 1.0e12),
    'rate_divisor': RATE_DIVISOR_RANGE,
}
#: The record's processing switches (:class:`.ground_motion.Processing`, in its order).
PROCESSING_KEYS = ('record_resample', 'record_remove_mean', 'record_baseline')
#: Default of every parameter (None: see :data:`PARAMS`).
DEFAULTS = {key: default for key, (default, _) in PARAMS.items()}


def param_schema(node_params) -> dict:
    """Return the numerical node's parameter schema: its ``node_params`` and the core's."""
    return node_schema(node_params, {**EXCITATION_PARAMS, **PARAMS},
                       {**EXCITATION_RANGES, **RANGES})


class NumericalSubstructure(SteppedSubstructure):
    """Numerical part of an RTHS (seed eq. 25) advanced one loop step per measured force."""

    backend = 'builtin'

    def __init__(self, model: LinearModel, ground_accel, dt, integrator='cr', rho_inf=0.5,
                 interface_dofs=None, force_scale=1.0, interface_frame='absolute',
                 specimen_mass_kg=0.0, ground_disp=None, motion=None):
        """Set up the model, the ground acceleration [m/s^2] per step, and the integrator.

        ``ground_disp`` [m] is needed in the absolute frame; by default it is
        the trapezoidal double integral of ``ground_accel``.  ``motion``: the
        :class:`.ground_motion.GroundMotion` it came from (source, processing, t0).
        """
        self.motion = motion
        if interface_frame not in FRAMES:
            raise ValueError(f'interface_frame {interface_frame!r}: use absolute or relative')
        self.model = model
        self.dt = float(dt)
        self.ag = np.asarray(ground_accel, dtype=float)
        self.n_steps = int(self.ag.size)
        if self.n_steps < 2:
            raise ValueError('the ground motion has fewer than 2 steps; check duration_s')
        self.ug = (integrate(self.ag, self.dt)[1] if ground_disp is None
                   else np.asarray(ground_disp, dtype=float))
        self.iface = list(model.interface_dofs if interface_dofs is None else interface_dofs)
        for i in self.iface:
            if not 0 <= int(i) < model.n:
                raise ValueError(f'interface_dofs: {i} is outside 0..{model.n - 1}')
        self.n_interface = len(self.iface)
        self.force_scale = float(force_scale)
        self.frame = interface_frame
        self.specimen_mass = float(specimen_mass_kg)
        self.integrator = integrator
        self.integ = make_integrator(integrator, model.M, model.C, model.K, self.dt, rho_inf)
        self._mg = model.M @ model.gamma
        # external force F s(t_k) [N] of steps 0..n_steps (predict() may read step n_steps)
        self._force_ext = model.external_force if model.has_external_force else None
        self._force_ext_scale = (model.external_force_scale(np.arange(self.n_steps + 1)
                                                            * self.dt)
                                 if self._force_ext is not None else None)
        self._gi = model.gamma[self.iface]
        # per-step constants of advance(): index array, whether predict() reads the load
        self._iface_idx = np.asarray(self.iface, dtype=np.intp)
        self._predict_needs_load = self.integ.predict_uses_load
        self._relative_load = self.frame == 'relative' and bool(self.specimen_mass)
        self._absolute = self.frame == 'absolute'
        self.reset()

    def reset(self):
        """Return to step 0 at rest (same model, ground motion and settings)."""
        n, ns = self.model.n, self.n_steps
        self._k = 0
        self._d = np.zeros((ns, n))
        self._a_out = np.zeros(ns)
        self._cmd = np.zeros((ns, self.n_interface))
        self._force = np.zeros((ns, self.n_interface))
        self._cmd[0] = self._command(np.zeros(n), 0)

    def load(self, k):
        """Load vector ``p_k`` [N]: ``-M Gamma a_g + F s(t_k)`` plus ``P_I^E`` (relative frame)."""
        a = self.ag[k] if k < self.n_steps else 0.0
        p = -self._mg * a
        if self._force_ext_scale is not None:  # set together with _force_ext
            p += self._force_ext * self._force_ext_scale[min(k, self.n_steps)]
        if self._relative_load:
            p[self.iface] -= self.force_scale * self.specimen_mass * self._gi * a
        return p

    def _command(self, d, k):
        u = d.take(self._iface_idx)
        if self._absolute:
            u = u + self._gi * (self.ug[k] if k < self.n_steps else self.ug[-1])
        return u

    def first_displacement(self) -> np.ndarray:
        """Interface displacement command of step 0 [m] (structure at rest)."""
        return self._cmd[0].copy()

    def advance(self, measured_force) -> np.ndarray:
        """Finish step k with its measured force [N]; return the command of step k+1 [m]."""
        f = self.force_of(measured_force)
        k = self._k
        integ = self.integ
        r = np.zeros(self.model.n)
        r[self._iface_idx] = self.force_scale * f
        p = self.load(k)
        if k == 0:
            integ.set_state(np.zeros(self.model.n), np.zeros(self.model.n), p=p, r=r)
        else:
            integ.correct(p, r)
        self._force[k] = f
        self._d[k] = integ.d
        self._a_out[k] = integ.a[self.model.output_dof]
        self._k = k + 1
        # CR and KR-alpha are explicit: their predict() does not read the next load
        d_next = integ.predict(self.load(k + 1) if self._predict_needs_load else None)
        cmd = self._command(d_next, k + 1)
        if k + 1 < self.n_steps:
            self._cmd[k + 1] = cmd
        return cmd

    def done(self) -> bool:
        """Return True once ``n_steps`` steps are finished."""
        return self._k >= self.n_steps

    def state(self) -> dict:
        """Step count, time [s], interface and output displacement [m] of the last finished step."""
        k = self._k
        last = self._d[k - 1] if k else np.full(self.model.n, np.nan)
        return {'step': k, 'time': (k - 1) * self.dt if k else float('nan'),
                'interface_disp': last[self._iface_idx].copy(),
                'output_disp': float(last[self.model.output_dof])}

    def history(self) -> dict:
        """Arrays of the finished steps (SI units) for the review and the reference comparison."""
        k = self._k
        out = self.model.output_dof
        return {
            'time': np.arange(k) * self.dt,
            'ground_accel': self.ag[:k].copy(),
            'ground_disp': self.ug[:k].copy(),
            'displacements': self._d[:k].copy(),
            'output_disp': self._d[:k, out].copy(),
            'output_accel_abs': self._a_out[:k] + self.model.gamma[out] * self.ag[:k],
            'interface_disp': self._d[:k][:, self.iface].copy(),
            'command': self._cmd[:k].copy(),
            'measured_force': self._force[:k].copy(),
        }


def _num(params, key, positive=True, allow_zero=False):
    val = params.get(key, DEFAULTS.get(key))
    try:
        val = float(val)
    except (TypeError, ValueError):
        raise ValueError(f'parameter {key} = {val!r} must be a number') from None
    if not math.isfinite(val) or (positive and (val < 0 or (val == 0 and not allow_zero))):
        raise ValueError(f'parameter {key} = {val} must be a positive finite number')
    return val


def build_model(params) -> LinearModel:
    """Model named by ``params['model']`` ('sdof', 'building2story' or a YAML path)."""
    name = str(params.get('model', DEFAULTS['model']))
    if name == 'sdof':
        return sdof_model(_num(params, 'sdof_mass_kg'), _num(params, 'sdof_freq_hz'),
                          _num(params, 'sdof_zeta', allow_zero=True))
    if name == 'building2story':
        mass = params.get('building_mass_kg') or BUILDING_MASS_KG
        return building_16dof(float(mass))
    if name.startswith('silva2020_case'):
        return model_by_name(name)
    if name.endswith(('.yaml', '.yml')):
        try:
            return load_model_yaml(name)
        except FileNotFoundError:
            raise ValueError(f'parameter model = {name!r}: file not found; give an existing '
                             'model YAML path, or sdof / building2story') from None
    raise ValueError(f'parameter model = {name!r}: use sdof, building2story or a .yaml path')


def model_script_path(name: str):
    """Return the OpenSeesPy model script ``name`` names, or None for other models.

    A ``.py`` path, or a name such as ``frame-steel01`` for
    ``$RTHS_ROOT/config/models/frame_steel01.py`` (the scripts shipped in config/).
    """
    if name.endswith('.py'):
        return name
    if name in ('sdof', 'building2story', 'excitation') or name.endswith(('.yaml', '.yml')):
        return None
    shipped = os.path.join(os.environ.get('RTHS_ROOT', '.'), 'config', 'models',
                           name.replace('-', '_') + '.py')
    return shipped if os.path.isfile(shipped) else None


def make_substructure(params: dict, model: Any = None, motion=None) -> SteppedSubstructure:
    """Build the substructure the parameters describe (module docstring).

    ``backend: builtin`` gives a :class:`NumericalSubstructure`, ``backend:
    opensees`` an :class:`.opensees_backend.OpenSeesSubstructure` (OpenSeesPy
    needed; OSError naming the fix when it is absent).

    ``model: excitation`` returns a :class:`~.excitation.PrescribedExcitation`
    instead (the identification run: a BLWN interface displacement).

    ``model`` (a LinearModel) and ``motion`` (a prepared GroundMotion at ``fs_hz``)
    replace reading the model file and the record: a bag's own copies (:mod:`.inputs`).
    """
    params = {k: v for k, v in dict(params).items()
              if v is not None and k not in ROS_KEYS and not k.startswith('qos_overrides')}
    if params.get('model') == 'excitation':
        return make_excitation(params)
    if params.get('interface_dofs') is not None and len(np.atleast_1d(
            params['interface_dofs'])) == 0:
        params.pop('interface_dofs')  # ROS cannot express "unset" for a list
    unknown = set(params) - set(DEFAULTS)
    if unknown:
        raise ValueError(f'unknown parameter(s) {", ".join(sorted(unknown))}; '
                         f'known: {", ".join(DEFAULTS)}')
    backend = str(params.get('backend', 'builtin'))
    if backend not in BACKENDS:
        raise ValueError(f'parameter backend = {backend!r}: use {" or ".join(BACKENDS)}')
    script = model_script_path(str(params.get('model', DEFAULTS['model'])))
    if script and backend != 'opensees':
        raise ValueError(f'parameter model = {params["model"]!r} is an OpenSeesPy model script: '
                         'set backend: opensees')
    if script and params.get('interface_dofs') is not None:
        raise ValueError('parameter interface_dofs: a model script names its interface itself '
                         '(interface_node, interface_dof)')
    if script:
        builder, ground_dof = script_builder(script)
        model = ScriptModel(script, gamma=1.0 if ground_dof == 1 else 0.0)
    elif model is None and params.get('model') == MARTHS_MODEL:
        if (str(params.get('record', DEFAULTS['record'])) in ('harmonic', 'blwn', 'none')
                or backend != 'builtin'):
            raise ValueError("parameter model = 'marths': give a record file and the builtin "
                             'backend (its own Newmark integrator)')
    elif model is None:
        model = build_model(params)
    integ = str(params.get('integrator') or
                ('cr' if backend == 'builtin' else 'central_difference'))
    if backend == 'builtin' and integ not in INTEGRATORS:
        raise ValueError(f'parameter integrator = {integ!r}: use one of {", ".join(INTEGRATORS)}')
    rho = _num(params, 'rho_inf', allow_zero=True)
    if rho > 1:
        raise ValueError(f'parameter rho_inf = {rho} must lie in [0, 1]')
    fs = _num(params, 'fs_hz')
    frame = str(params.get('interface_frame', 'absolute'))
    if frame not in FRAMES:
        raise ValueError(f'parameter interface_frame = {frame!r}: use absolute or relative')
    record = str(params.get('record', DEFAULTS['record']))
    scale = _num(params, 'scale', positive=False)
    duration = params.get('duration_s')
    duration = None if duration in (None, 0, 0.0) else _num(params, 'duration_s')
    if duration is not None:
        check_run_steps(duration, fs)
    dt = 1.0 / fs
    if record == 'harmonic':
        f_h = params.get('harmonic_freq_hz')
        if not f_h and script:
            raise ValueError('parameter harmonic_freq_hz: give it for a model script (rths '
                             'cannot compute the modes of an OpenSees model)')
        f_h = float(f_h or model.modes()[0][0])
        if not 0 < f_h < fs / 2:
            raise ValueError(f'parameter harmonic_freq_hz = {f_h} must lie in (0, fs_hz/2)')
        t = np.arange(int(round((duration or 10.0) * fs))) * dt
        ag = scale * G * np.sin(2 * math.pi * f_h * t)
    elif record == 'blwn':
        ag = ground_motion('blwn', fs, scale, duration or 10.0, rng=int(params.get('seed', 0)),
                           blwn_band_hz=_num(params, 'blwn_band_hz'))
    elif record == 'none':
        ag = np.zeros(int(round((duration or 10.0) * fs)))
    processing = Processing(*(bool(params.get(k, DEFAULTS[k])) for k in PROCESSING_KEYS))
    if motion is not None:        # the record as the run used it (a bag's own copy)
        ug = integrate(motion.accel, motion.dt)[1]
    elif record in ('harmonic', 'blwn', 'none'):
        motion = GroundMotion(ag, dt, record, 'synthetic', 'g', processing=(
            f'{record} at the loop rate, peak {scale:g} g' if record != 'none' else 'none',))
        if record != 'none':
            motion, ug = prepare(motion, fs, 1.0, None, processing._replace(resample=False))
        else:
            ug = ag * 0
    else:
        try:
            raw = read_record(record, str(params.get('record_format') or ''),
                              str(params.get('record_units') or ''),
                              _num(params, 'record_dt_s', allow_zero=True))
            motion, ug = prepare(raw, fs, scale, duration, processing)
        except ValueError as err:
            raise ValueError(f'parameter record: {err}') from None
    ag = motion.accel
    n = rate_divisor(params, fs, record)
    if params.get('model') == MARTHS_MODEL:
        if n > 1:
            raise ValueError("parameter rate_divisor: model 'marths' runs at the loop rate (its "
                             'own Newmark integrator): use 1')
        return MarthsSubstructure(ag, dt, motion)
    iface = params.get('interface_dofs')
    if iface is not None:
        iface = [int(i) for i in np.atleast_1d(iface)]
        if not iface or any(not 0 <= i < model.n for i in iface):
            raise ValueError(f'parameter interface_dofs = {iface}: give DOF indices in '
                             f'0..{model.n - 1} (model {model.name})')
    fscale = params.get('force_scale')
    fscale = (5.0 if params.get('model') == 'building2story' else 1.0) if fscale is None \
        else _num(params, 'force_scale', allow_zero=True)
    mass = _num(params, 'specimen_mass_kg', allow_zero=True)
    # n > 1: the substructure takes every n-th loop sample (multirate.py)
    sub: SteppedSubstructure
    if backend == 'opensees':
        if not script:
            builder = linear_model_builder(model, model.interface_dofs if iface is None
                                           else iface)
        sub = OpenSeesSubstructure(builder, model, ag[::n], dt * n, integ, iface, fscale, frame,
                                   mass, ug[::n])
        sub.motion = motion if n == 1 else None
    else:
        sub = NumericalSubstructure(model, ag[::n], dt * n, integ, rho, iface, fscale, frame,
                                    mass, ug[::n], motion if n == 1 else None)
    return sub if n == 1 else MultiRateSubstructure(sub, n, ag, ug, motion)


def rate_divisor(params: dict, fs: float, record: str = '') -> int:
    """Return the parameter ``rate_divisor`` (1 if unset); ValueError naming what to fix.

    The numerical rate ``fs / rate_divisor`` must sample the synthetic excitations
    (``harmonic_freq_hz``, ``blwn_band_hz``) below its Nyquist frequency.
    """
    value = params.get('rate_divisor', 1)
    low, high = RATE_DIVISOR_RANGE
    if (isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating))
            or not float(value).is_integer() or not low <= value <= high):
        raise ValueError(f'parameter rate_divisor = {value!r}: give a whole number in '
                         f'{low}..{high} (1: the substructure at the loop rate)')
    n = int(value)
    nyquist = fs / n / 2
    band = (params.get('harmonic_freq_hz') if record == 'harmonic'
            else _num(params, 'blwn_band_hz') if record == 'blwn' else None)
    if n > 1 and band and float(band) >= nyquist:
        raise ValueError(f'parameter rate_divisor = {n}: the numerical rate {fs / n:g} Hz does '
                         f'not sample the {record} excitation ({float(band):g} Hz; its Nyquist '
                         f'frequency is {nyquist:g} Hz): lower rate_divisor')
    return n
