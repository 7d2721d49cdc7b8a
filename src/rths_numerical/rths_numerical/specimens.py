"""Specimens: the registry from a specimen's name to its physics and to what it implies.

The specimen is the physical part of an RTHS, in the lab on the shake table and here in
the simulated plant (rths_actuator_bridge.simulated).  A :class:`Specimen` entry holds
everything the layers above need, so none of them compares a specimen's name:

* its physics, one of: ``table_mass``, a mass-spring-damper carried by the table (eq. 46,
  :class:`.dtm.DTMParameters`, driven by the table's acceleration; ``table_mass_of``: the
  same built from the specimen's settings), or ``device``, a
  device between the table and the ground driven by its stroke (built from the bridge's
  settings: ``reset()``, ``advance(x0, v0, x1, v1, h)``, ``force()``);
* ``frame_mass_kg``: mass the load cells carry with the table (the DTM's frame);
* ``interface_frame``: the frame of the interface displacement the table must follow
  (``absolute`` for a specimen riding the table, ``relative`` for one between the floor and
  the ground) and so :meth:`Specimen.numerical_params`, the numerical substructure's
  ``interface_frame`` and ``specimen_mass_kg`` (seed eq. 24);
* ``params`` and ``ranges``: the bridge parameters it reads (e.g. ``mr_voltage_v``);
* :meth:`Specimen.reference`: the specimen on a perfect actuator (table displacement ->
  measured force), for the whole-numerical reference of the review.

The Table 4 configurations are entered from :data:`.dtm.TABLE4`; ``none`` is the bare
table and ``mr`` the MR damper of :mod:`.mr_damper`.  A lab's own: ``spring`` (a linear
spring-damper with an optional mass, between the floor and the ground), ``oscillator`` (a
generic SDOF riding the table) and ``statespace`` (a linear state-space model from a
file, :mod:`.state_space_specimen`).  :meth:`Specimen.check` validates a specimen's
settings against the model before a run starts.  docs/extending.md adds a specimen.
"""

from dataclasses import dataclass, field
import math
from typing import Callable

from rths_common.params import Spec, check_range
from rths_common.registry import Registry

from .dtm import FRAME_MASS_KG, SEED_CONFIGURATION, TABLE4, TABLE4_PRINTED, DTMParameters
from .mr_damper import MRDamper, check_voltage
from .reference import DTMSpecimen, StrokeSpecimen
from .spring_damper import SpringDamper
from .state_space_specimen import StateSpaceSpecimen, load_state_space


@dataclass(frozen=True)
class Specimen:
    """One specimen: its physics, its parameters and the interface frame it implies."""

    summary: str
    table_mass: DTMParameters | None = None     # a mass on the table (eq. 46)
    device: Callable | None = None              # settings -> a stroke device (see module doc)
    frame_mass_kg: float = 0.0                  # [kg] carried by the load cells with the table
    interface_frame: str = 'absolute'          # one of substructure.FRAMES
    params: dict = field(default_factory=dict)  # bridge key -> (type, default, meaning)
    ranges: dict = field(default_factory=dict)  # bridge key -> inclusive (low, high)
    substeps_param: str = ''                    # the key of params giving the device's sub-steps
    hysteresis: bool = False                    # the review plots its force against its stroke
    table_mass_of: Callable | None = None       # settings -> DTMParameters (a mass on the table)
    frame_mass_param: str = ''                  # the key of params giving frame_mass_kg
    moving_mass_param: str = ''                 # relative frame: the key of its moving mass [kg]

    def mass_on_table(self, params: dict | None = None) -> DTMParameters | None:
        """Return the mass-spring-damper the table carries (None if the specimen has none)."""
        if self.table_mass_of is not None:
            return self.table_mass_of(self.settings(params or {}))
        return self.table_mass

    def frame_mass(self, params: dict | None = None) -> float:
        """Return the mass [kg] the load cells carry with the table."""
        if self.frame_mass_param:
            return float(self.settings(params or {})[self.frame_mass_param])
        return self.frame_mass_kg

    def specimen_mass(self, params: dict | None = None) -> float:
        """Return the mass [kg] of one specimen moving with the floor (P_I^E, seed eq. 24)."""
        if self.interface_frame != 'absolute':
            return (float(self.settings(params or {})[self.moving_mass_param])
                    if self.moving_mass_param else 0.0)
        mass = self.mass_on_table(params)
        return self.frame_mass(params) + (mass.m_d if mass is not None else 0.0)

    @property
    def specimen_mass_kg(self) -> float:
        """Return :meth:`specimen_mass` with the default settings."""
        return self.specimen_mass()

    def numerical_params(self, params: dict | None = None) -> dict:
        """Return the numerical substructure's parameters this specimen implies."""
        return {'interface_frame': self.interface_frame,
                'specimen_mass_kg': self.specimen_mass(params)}

    def check(self, params: dict, n_interface: int, model_name: str = 'the model') -> None:
        """Refuse settings this specimen cannot run with ``n_interface`` interface DOFs."""
        if n_interface != 1:
            raise ValueError(f'{model_name} has {n_interface} interface DOFs, a specimen drives '
                             'one actuator: give the model one interface DOF (interface_dofs)')
        self.mass_on_table(params)              # builds it: a bad setting raises here
        device, _ = self.make_device(params)
        if device is not None:
            device.reset()

    def settings(self, params: dict) -> dict:
        """Return this specimen's parameters from ``params`` (the bridge's), defaults filled."""
        return {key: typ(params.get(key, default))
                for key, (typ, default, _) in self.params.items()}

    def make_device(self, params: dict):
        """Return ``(device, substeps)`` built from the bridge's ``params`` (None if no device)."""
        if self.device is None:
            return None, 1
        settings = self.settings(params)
        return self.device(settings), int(settings.get(self.substeps_param, 1))

    def reference(self, dt: float, params: dict | None = None):
        """Return the specimen on a perfect actuator (``f = spec(x)``), None for a bare table."""
        mass = self.mass_on_table(params)
        if mass is not None:
            return DTMSpecimen(mass, dt, self.frame_mass(params))
        device, substeps = self.make_device(params or {})
        return None if device is None else StrokeSpecimen(device, dt, substeps)


def _mr_device(settings: dict) -> MRDamper:
    return MRDamper(voltage=check_voltage(settings['mr_voltage_v']))


#: Specimen name -> entry (the allowed values of the bridge's ``specimen`` and
#: ``rths run --specimen``).
SPECIMENS = Registry('specimen', 'specimen')
for _name, _dtm in TABLE4.items():
    SPECIMENS.add(_name, Specimen(
        f'the DTM in configuration {_name} of Table 4 (zeta {TABLE4_PRINTED[_name][0]:g} %, '
        f'f_n {TABLE4_PRINTED[_name][1]:g} Hz)', table_mass=_dtm, frame_mass_kg=FRAME_MASS_KG))
SPECIMENS.add('none', Specimen('the bare shake table: no specimen, no force'))
SPECIMENS.add('mr', Specimen(
    'an MR damper between the floor and the ground (Spencer et al. 1997); the table follows '
    'the floor relative to the ground', device=_mr_device, interface_frame='relative',
    params={'mr_voltage_v': (float, 1.0, '[V] constant command voltage of the MR damper'),
            'mr_substeps': (int, 8, '[-] RK4 sub-steps per sample of the MR damper model')},
    ranges={'mr_voltage_v': (0.0, 10.0), 'mr_substeps': (1, 4096)},
    substeps_param='mr_substeps', hysteresis=True))
SPECIMENS.add('spring', Specimen(
    'a linear spring-damper (optional mass) between the floor and the ground',
    interface_frame='relative', moving_mass_param='spring_mass_kg',
    device=lambda s: SpringDamper(s['spring_k_n_m'], s['spring_c_n_s_m'], s['spring_mass_kg']),
    params={'spring_k_n_m': (float, 2.0e5, '[N/m] stiffness of the spring-damper'),
            'spring_c_n_s_m': (float, 3.0e3, '[N s/m] damping of the spring-damper'),
            'spring_mass_kg': (float, 0.0, '[kg] mass of the spring-damper moving with the '
                               'floor')},
    ranges={'spring_k_n_m': (0.0, 1.0e9), 'spring_c_n_s_m': (0.0, 1.0e7),
            'spring_mass_kg': (0.0, 1.0e6)}))


def _oscillator(settings: dict) -> DTMParameters:
    mass, freq, zeta = (settings[k] for k in ('oscillator_mass_kg', 'oscillator_freq_hz',
                                              'oscillator_zeta'))
    if not (mass > 0 and freq > 0):
        raise ValueError(f'specimen oscillator: oscillator_mass_kg = {mass:g} and '
                         f'oscillator_freq_hz = {freq:g} must be > 0')
    omega = 2.0 * math.pi * freq
    return DTMParameters(mass, 2.0 * zeta * mass * omega, mass * omega ** 2)


SPECIMENS.add('oscillator', Specimen(
    'a generic SDOF (mass, frequency, damping ratio) on a frame riding the table',
    table_mass_of=_oscillator, frame_mass_param='oscillator_frame_kg',
    params={'oscillator_mass_kg': (float, 50.0, '[kg] moving mass of the SDOF specimen'),
            'oscillator_freq_hz': (float, 3.0, '[Hz] natural frequency of the SDOF specimen'),
            'oscillator_zeta': (float, 0.05, '[-] damping ratio of the SDOF specimen'),
            'oscillator_frame_kg': (float, 0.0, '[kg] frame of the SDOF specimen, on the load '
                                    'cells')},
    ranges={'oscillator_mass_kg': (0.0, 1.0e6), 'oscillator_freq_hz': (0.0, 1000.0),
            'oscillator_zeta': (0.0, 10.0), 'oscillator_frame_kg': (0.0, 1.0e6)}))
SPECIMENS.add('statespace', Specimen(
    'a linear state-space model from a file (stroke, velocity -> force) between the floor '
    'and the ground', interface_frame='relative',
    device=lambda s: StateSpaceSpecimen(load_state_space(s['statespace_file'])),
    params={'statespace_file': (str, '', 'YAML file with A, B, C, D of the state-space '
                                'specimen (rths_numerical/state_space_specimen.py)')}))

#: The specimen of a params file or a run that names none (the seed's).
DEFAULT_SPECIMEN = SEED_CONFIGURATION


def specimen_params() -> tuple:
    """Return ``(params, ranges)`` of every specimen (the bridge's schema adds them)."""
    params, ranges = {}, {}
    for entry in SPECIMENS.values():
        params.update(entry.params)
        ranges.update(entry.ranges)
    return params, ranges


def specimen_of(bridge: dict) -> str:
    """Return the specimen a bridge's parameters name (also under the former key ``dtm``)."""
    return str(bridge.get('specimen', bridge.get('dtm', DEFAULT_SPECIMEN)))


def specimen_settings(name: str, pairs, where: str) -> dict:
    """Return ``KEY=VALUE`` ``pairs`` as the specimen ``name``'s checked parameters.

    ValueError (naming ``where``) for a key the specimen does not take, a value of the
    wrong type or outside its range.
    """
    entry = SPECIMENS.entry(name, where)
    out = {}
    for pair in pairs:
        key, sep, text = str(pair).partition('=')
        if not sep or key not in entry.params:
            raise ValueError(f'{where} {pair}: specimen {name} takes '
                             f'{", ".join(entry.params) or "no parameters"} (KEY=VALUE)')
        typ, _, meaning = entry.params[key]
        try:
            value = typ(float(text)) if typ is int else typ(text)
        except ValueError:
            raise ValueError(f'{where} {pair}: {text!r} is not a {typ.__name__}') from None
        check_range(key, value, Spec(meaning, entry.ranges.get(key)))
        out[key] = value
    return out
