"""Specimens: the registry from a specimen's name to its physics and to what it implies.

The specimen is the physical part of an RTHS, in the lab on the shake table and here in
the simulated plant (rths_actuator_bridge.simulated).  A :class:`Specimen` entry holds
everything the layers above need, so none of them compares a specimen's name:

* its physics, one of: ``table_mass``, a mass-spring-damper carried by the table (eq. 46,
  :class:`.dtm.DTMParameters`, driven by the table's acceleration), or ``device``, a
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
table and ``mr`` the MR damper of :mod:`.mr_damper`.  docs/extending.md adds a specimen.
"""

from dataclasses import dataclass, field
from typing import Callable

from rths_common.params import Spec, check_range
from rths_common.registry import Registry

from .dtm import FRAME_MASS_KG, SEED_CONFIGURATION, TABLE4, TABLE4_PRINTED, DTMParameters
from .mr_damper import MRDamper, check_voltage
from .reference import DTMSpecimen, StrokeSpecimen
from .spring_damper import SpringDamper


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

    @property
    def specimen_mass_kg(self) -> float:
        """Return the mass [kg] of one specimen moving with the table (P_I^E, seed eq. 24)."""
        moving = self.table_mass.m_d if self.table_mass is not None else 0.0
        return self.frame_mass_kg + moving if self.interface_frame == 'absolute' else 0.0

    def numerical_params(self) -> dict:
        """Return the numerical substructure's parameters this specimen implies."""
        return {'interface_frame': self.interface_frame,
                'specimen_mass_kg': self.specimen_mass_kg}

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
        if self.table_mass is not None:
            return DTMSpecimen(self.table_mass, dt, self.frame_mass_kg)
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
    'a linear spring-damper between the floor and the ground', interface_frame='relative',
    device=lambda s: SpringDamper(s['spring_k_n_m'], s['spring_c_n_s_m']),
    params={'spring_k_n_m': (float, 2.0e5, '[N/m] stiffness of the spring-damper'),
            'spring_c_n_s_m': (float, 3.0e3, '[N s/m] damping of the spring-damper')},
    ranges={'spring_k_n_m': (0.0, 1.0e9), 'spring_c_n_s_m': (0.0, 1.0e7)}))

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
