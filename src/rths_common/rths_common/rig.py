"""A multi-actuator rig as a lab describes it: actuators, coupler geometry, interface DOFs.

One YAML file (``config/rig_two_actuators.yaml`` is the example; docs/multi_actuator.md the
guide) gives the bridge everything that differs from a one-actuator test::

    rig:
      name: ...                     # free text
      dofs: [x, theta]              # the interface DOFs, in this order
      coupler:
        offsets_m: [[x1, y1], ...]  # attachment point of each actuator from the node [m]
        kinematics: exact           # exact (large rotations) | linear
      interface_limits:             # optional; checked on every command and reading
        x_m: ...                    # |x| [m]
        theta_rad: ...              # |theta| [rad]
        force_n: ...                # |F| at the node [N]
        moment_n_m: ...             # |M| at the node [N m]
      actuators:                    # one per command channel, in channel order
        - name: ...
          stroke_m: ...             # any of ACTUATOR_LIMITS; a missing one takes the
                                    # bridge's one-number parameter

:class:`Rig` is the one place where actuator strokes and interface DOFs meet
(:class:`rths_common.coupler.Coupler`): :meth:`Rig.to_strokes`, :meth:`Rig.to_dofs`,
:meth:`Rig.interface_forces`, and the interface checks.  Every bad entry is refused with a
ValueError naming the file and the field.
"""

from dataclasses import dataclass

import numpy as np

from . import yamlfile
from .coupler import Coupler

#: Limits an actuator entry may give (SI); the bridge's per-channel safety limits
#: (rths_actuator_bridge.safety.PER_CHANNEL, checked equal by its tests).
ACTUATOR_LIMITS = ('stroke_m', 'velocity_m_s', 'acceleration_m_s2', 'force_n', 'dtm_rel_disp_m',
                   'safe_position_m', 'instability_tracking_m', 'instability_force_n')
#: Interface limits: key -> the interface quantity it bounds.
INTERFACE_LIMITS = {'x_m': 'translation x [m]', 'theta_rad': 'rotation theta [rad]',
                    'force_n': 'force F at the node [N]',
                    'moment_n_m': 'moment M at the node [N m]'}
#: Interface DOFs a coupler resolves, in the order of :meth:`Coupler.dofs`.
DOFS = ('x', 'theta')
#: Each DOF's SI unit, the unit reports print it in, and the factor from the one to the other.
DOF_UNITS = {'x': ('m', 'mm', 1e3), 'theta': ('rad', 'mrad', 1e3)}
KINEMATICS = ('exact', 'linear')


def _number(value, where: str, positive: bool = True) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise ValueError(f'{where} = {value!r} must be a finite number')
    if positive and value <= 0:
        raise ValueError(f'{where} = {value!r} must be > 0')
    return float(value)


def _mapping(value, where: str, known) -> dict:
    if not isinstance(value, dict):
        raise ValueError(f'{where} must be a mapping (key: value lines)')
    unknown = sorted(set(value) - set(known))
    if unknown:
        raise ValueError(f'{where}: unknown key(s) {", ".join(map(str, unknown))}; known: '
                         f'{", ".join(known)}')
    return value


@dataclass(frozen=True)
class Rig:
    """Actuators (names, per-actuator limits), coupler and interface limits of one rig."""

    name: str
    dofs: tuple
    coupler: Coupler
    linear: bool
    actuators: tuple          # names, in channel order
    limits: dict              # limit key -> tuple of one value (or None) per actuator
    interface: dict           # interface limit key -> value
    where: str = 'rig'

    @property
    def n(self) -> int:
        """Return the number of actuators (command channels)."""
        return len(self.actuators)

    @classmethod
    def from_dict(cls, data, where: str = 'rig file') -> 'Rig':
        """Build from the parsed file (its top key ``rig``); ValueError naming the field."""
        top = _mapping(data, where, ('rig',))
        if 'rig' not in top:
            raise ValueError(f'{where}: no top-level key rig (see config/rig_two_actuators.yaml)')
        at = f'{where}: rig'
        rig = _mapping(top['rig'], at, ('name', 'dofs', 'coupler', 'interface_limits',
                                        'actuators'))
        for key in ('dofs', 'coupler', 'actuators'):
            if key not in rig:
                raise ValueError(f'{at}.{key} is missing (see config/rig_two_actuators.yaml)')
        dofs = rig['dofs']
        if not isinstance(dofs, list) or tuple(dofs) != DOFS:
            raise ValueError(f'{at}.dofs = {dofs!r}: a coupler drives the DOFs '
                             f'[{", ".join(DOFS)}] in this order; give exactly that list')
        coup = _mapping(rig['coupler'], f'{at}.coupler', ('offsets_m', 'kinematics'))
        kin = coup.get('kinematics', 'exact')
        if kin not in KINEMATICS:
            raise ValueError(f'{at}.coupler.kinematics = {kin!r}: use {" or ".join(KINEMATICS)}')
        offsets = coup.get('offsets_m')
        if (not isinstance(offsets, list) or not offsets
                or not all(isinstance(o, list) and len(o) == 2 for o in offsets)):
            raise ValueError(f'{at}.coupler.offsets_m must be a list of [x, y] pairs [m], one '
                             'per actuator (its attachment point from the interface node)')
        xy = [[_number(v, f'{at}.coupler.offsets_m[{i}][{j}]', positive=False)
               for j, v in enumerate(o)] for i, o in enumerate(offsets)]
        try:
            coupler = Coupler.from_offsets(xy)
        except ValueError as err:
            raise ValueError(f'{at}.coupler.offsets_m: {err}') from None
        acts = rig['actuators']
        if not isinstance(acts, list) or len(acts) != len(xy):
            raise ValueError(f'{at}.actuators must list one entry per coupler offset '
                             f'({len(xy)}), in channel order')
        names: list = []
        limits: dict[str, list] = {key: [] for key in ACTUATOR_LIMITS}
        for i, act in enumerate(acts):
            aw = f'{at}.actuators[{i}]'
            act = _mapping(act, aw, ('name',) + ACTUATOR_LIMITS)
            name = act.get('name')
            if not isinstance(name, str) or not name or name in names:
                raise ValueError(f'{aw}.name = {name!r} must be a non-empty name used once')
            names.append(name)
            for key in ACTUATOR_LIMITS:
                value = act.get(key)
                limits[key].append(None if value is None else _number(
                    value, f'{aw}.{key}', positive=key != 'safe_position_m'))
        inter = _mapping(rig.get('interface_limits') or {}, f'{at}.interface_limits',
                         tuple(INTERFACE_LIMITS))
        interface = {k: _number(v, f'{at}.interface_limits.{k}') for k, v in inter.items()}
        name = rig.get('name', '')
        return cls(str(name), tuple(dofs), coupler, kin == 'linear', tuple(names),
                   {k: tuple(v) for k, v in limits.items()}, interface, where)

    def bridge_params(self, params: dict) -> dict:
        """Return the bridge's flat ``params`` with this rig's per-actuator limits as lists.

        An actuator that does not give a limit takes the parameter (one number for all, or
        its own entry of a list of one per actuator; the parameter's default when it is
        absent too, left to the bridge).
        """
        out = dict(params)
        for key, given in params.items():
            if key in self.limits and isinstance(given, (list, tuple)) and len(given) != self.n:
                raise ValueError(f'parameter {key} lists {len(given)} values but {self.where} '
                                 f'has {self.n} actuators ({", ".join(self.actuators)}); give '
                                 'one value per actuator, or one number for all')
        for key, values in self.limits.items():
            if all(v is None for v in values):
                continue
            if any(v is None for v in values) and key not in params:
                missing = [self.actuators[i] for i, v in enumerate(values) if v is None]
                raise ValueError(f'{self.where}: {key} is given for some actuators but not for '
                                 f'{", ".join(missing)}, and the bridge parameters give none; '
                                 'give it for every actuator')
            given = params.get(key)
            per = (list(given) if isinstance(given, (list, tuple)) else [given] * self.n)
            out[key] = [per[i] if v is None else v for i, v in enumerate(values)]
        return out

    # ------------------------------------------------------------ kinematics
    def to_strokes(self, x, theta) -> np.ndarray:
        """Return the actuator strokes [m] of interface ``x`` [m], ``theta`` [rad]."""
        return self.coupler.strokes(x, theta, linear=self.linear)

    def to_dofs(self, strokes):
        """Return ``(x [m], theta [rad])`` of the actuator ``strokes`` [m]."""
        return self.coupler.dofs(strokes, linear=self.linear)

    def interface_forces(self, forces, theta=0.0):
        """Return ``(F [N], M [N m])`` at the node of the actuators' axial ``forces`` [N]."""
        return self.coupler.interface_forces(forces, 0.0 if self.linear else theta)

    # ------------------------------------------------------------ checks
    def check_command(self, strokes) -> str:
        """Return '' if the commanded ``strokes`` keep the interface in its limits, else why."""
        x, theta = self.to_dofs(np.asarray(strokes, float))
        return self._check_dofs(float(x), float(theta), 'command')

    def check_reading(self, strokes, forces) -> str:
        """Return '' if a reading keeps the interface in its limits, else the fault text."""
        x, theta = self.to_dofs(np.asarray(strokes, float))
        text = self._check_dofs(float(x), float(theta), 'measured')
        if text:
            return text
        f, m = self.interface_forces(np.asarray(forces, float), theta)
        for key, value, unit in (('force_n', float(f), 'N'), ('moment_n_m', float(m), 'N m')):
            bound = self.interface.get(key)
            if bound is not None and abs(value) > bound:
                return (f'interface limit: measured {INTERFACE_LIMITS[key].split(" [")[0]} '
                        f'{value:.6g} {unit} > {bound:.6g} {unit} ({key})')
        return ''

    def _check_dofs(self, x: float, theta: float, what: str) -> str:
        for key, value, unit in (('x_m', x, 'm'), ('theta_rad', theta, 'rad')):
            bound = self.interface.get(key)
            if bound is not None and abs(value) > bound:
                return (f'interface limit: {what} {INTERFACE_LIMITS[key].split(" [")[0]} '
                        f'{value:.6g} {unit} > {bound:.6g} {unit} ({key})')
        return ''


def load_rig(path) -> Rig:
    """Read and check a rig file (module doc); ValueError naming the file and the field."""
    return Rig.from_dict(yamlfile.load(path), f'rig file {path}')
