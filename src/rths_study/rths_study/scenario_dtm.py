"""The seed's building with a DTM (chapter 7) as study scenarios, one grid point per run.

``dtm-tuning`` (seed 7.2): the DTM's natural frequency ``fn_hz`` and damping ``zeta``
on a building of first frequency ``f1_hz`` with a DTM of ``mass_ratio``, under BLWN
0-10 Hz with a 1 g peak.  ``building-frequency`` (seed 7.1): the building's first
frequency ``f1_hz`` and the DTM/building ``mass_ratio`` for a Table 4 DTM, under a
record.  Both return the four 2nd-floor criteria (max and RMS displacement [m] and
absolute acceleration [m/s^2]), computed in the frequency domain by
:func:`rths_numerical.studies.coupled_response`, the code of ``rths study dtm-tuning``
and ``rths study building-frequency``; ``config/studies/`` has their grids as SPECs.

Each run is transformed on its own (one FFT per point), so its numbers do not depend on
its chunk; the subcommands transform a row of the grid at once and agree to rounding.
"""

import functools
import math
import os

import numpy as np

from rths_numerical.dtm import TABLE4, dtm_configuration
from rths_numerical.ground_motion import RECORDS, G, baseline_correct, ground_motion
from rths_numerical.signals import blwn

from .scenarios import Scenario
from .setting import Setting

CRITERIA = {'max_disp': 'float', 'max_accel': 'float', 'rms_disp': 'float',
            'rms_accel': 'float'}
BUILDINGS = ('building2story', 'building2story-240')


def _model(name: str):
    # lazy: start-up cost: SciPy (~1 s), which this module needs only here
    from rths_numerical.building import building_16dof, building_240dof
    from rths_numerical.model import load_model_yaml
    if name == 'building2story':
        return building_16dof()
    if name == 'building2story-240':
        return building_240dof()
    return load_model_yaml(name)


@functools.lru_cache(maxsize=4)
def _building(name: str):
    """``(ModalBuilding, building mass [kg])`` of a model (once per process)."""
    # lazy: start-up cost: SciPy (~1 s), which this module needs only here
    from rths_numerical.studies import ModalBuilding
    model = _model(name)
    return ModalBuilding(model), float(model.gamma @ model.M @ model.gamma)


@functools.lru_cache(maxsize=4)
def _blwn(duration_s, fs_hz, seed):
    return blwn(duration_s, fs_hz, 10.0, 1.0 * G, rng=seed)


@functools.lru_cache(maxsize=8)
def _record(record, scale, fs_hz):
    ag, _, _ = baseline_correct(ground_motion(record, fs_hz, scale, None), 1.0 / fs_hz)
    return ag


def _criteria(building, ag, dt, m_d, c_d, k_d, scale) -> dict:

    # lazy: start-up cost: SciPy (~1 s), which this module needs only here
    from rths_numerical.studies import coupled_response
    disp, acc = coupled_response(building, ag, dt, m_d, c_d, k_d, scale)
    return {'max_disp': float(np.max(np.abs(disp))), 'max_accel': float(np.max(np.abs(acc))),
            'rms_disp': float(np.sqrt(np.mean(disp ** 2))),
            'rms_accel': float(np.sqrt(np.mean(acc ** 2)))}


def _check_building(name):
    if name not in BUILDINGS and not os.path.isfile(name):
        raise ValueError(f'scenario.building: {name!r} is not one of {", ".join(BUILDINGS)} '
                         'nor a model YAML file')


class DtmTuningScenario(Scenario):
    """Seed 7.2: DTM f_n x zeta on a building of given first frequency."""

    kind = 'dtm-tuning'
    summary = "seed 7.2: DTM natural frequency and damping, the four 2nd-floor criteria"
    settings = {'building': Setting(str, 'building2story',
                                    doc='building2story (16 DOF), building2story-240, or a '
                                        'model YAML path'),
                'mass_ratio': Setting(float, 0.01, minimum=0.0, maximum=1.0,
                                      doc='DTM mass over building mass'),
                'f1_hz': Setting(float, 2.81, minimum=0.01, doc='building first frequency'),
                'duration_s': Setting(float, 60.0, minimum=0.1, doc='BLWN length [s]'),
                'fs_hz': Setting(float, 256.0, minimum=1.0, doc='sampling rate [Hz]'),
                'signal_seed': Setting(int, 0, minimum=0, doc='seed of the BLWN')}
    parameters = {'fn_hz': Setting(float, minimum=0.0), 'zeta': Setting(float, minimum=0.0)}
    metrics = CRITERIA
    chunk = 50

    def check(self, spec):
        """Check that the building exists and that both parameters vary."""
        _check_building(spec.settings['building'])
        missing = {'fn_hz', 'zeta'} - set(spec.parameter_names)
        if missing:
            raise ValueError(f'parameters: vary both fn_hz and zeta (missing {sorted(missing)})')

    def evaluate(self, settings, runs):
        """Return the four criteria of each (fn_hz, zeta)."""
        building, total = _building(settings['building'])
        fs = settings['fs_hz']
        ag = _blwn(settings['duration_s'], fs, settings['signal_seed'])
        m_d = settings['mass_ratio'] * total
        scale = settings['f1_hz'] / building.f1
        out = []
        for run in runs:
            w = 2 * math.pi * run['params']['fn_hz']
            zeta = run['params']['zeta']
            out.append(_criteria(building, ag, 1.0 / fs, m_d, 2 * zeta * m_d * w, m_d * w * w,
                                 scale))
        return out


class BuildingFrequencyScenario(Scenario):
    """Seed 7.1: building f1 x DTM mass ratio for a Table 4 DTM under a record."""

    kind = 'building-frequency'
    summary = 'seed 7.1: building first frequency and DTM mass ratio, four criteria'
    settings = {'building': DtmTuningScenario.settings['building'],
                'damper': Setting(str, 'valve4', doc='Table 4 DTM configuration'),
                'scale': Setting(float, 0.10, minimum=0.0, doc='record scale factor'),
                'fs_hz': Setting(float, 200.0, minimum=1.0, doc='sampling rate [Hz]')}
    parameters = {'f1_hz': Setting(float, minimum=0.01),
                  'mass_ratio': Setting(float, minimum=0.0, maximum=1.0)}
    uses_records = True
    default_records = ('imperial_valley',)
    metrics = CRITERIA
    chunk = 50

    def check(self, spec):
        """Check building, damper and records exist and that both parameters vary."""
        _check_building(spec.settings['building'])
        if spec.settings['damper'] not in TABLE4:
            raise ValueError(f'scenario.damper: {spec.settings["damper"]!r} is not one of '
                             + ', '.join(TABLE4))
        for i, record in enumerate(spec.records):
            if record not in RECORDS and not os.path.isfile(record):
                raise ValueError(f'records[{i}]: {record!r} is not one of {", ".join(RECORDS)} '
                                 'nor a PEER .AT2 file')
        missing = {'f1_hz', 'mass_ratio'} - set(spec.parameter_names)
        if missing:
            raise ValueError(f'parameters: vary both f1_hz and mass_ratio (missing '
                             f'{sorted(missing)})')

    def evaluate(self, settings, runs):
        """Return the four criteria of each (f1_hz, mass_ratio)."""
        building, total = _building(settings['building'])
        dtm = dtm_configuration(settings['damper'])
        fs = settings['fs_hz']
        out = []
        for run in runs:
            ag = _record(run['record'], settings['scale'], fs)
            factor = run['params']['mass_ratio'] * total / dtm.m_d
            scale = run['params']['f1_hz'] / building.f1
            out.append(_criteria(building, ag, 1.0 / fs, dtm.m_d * factor, dtm.c_d * factor,
                                 dtm.k_d * factor, scale))
        return out
