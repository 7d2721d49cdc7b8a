"""The RTHS main job offline as a study scenario: ``rths-offline``, one RTHS run per run.

One run is step 3 and 4 of ``rths run`` without ROS: the three node cores, built from
the lab's params files (``config``: ``numerical.yaml``, ``bridge.yaml``, and the
compensator), step through :func:`rths_bringup.offline.offline_rths`, the order of the
lock-step node graph (a lock-step ``rths run`` gives the same arrays bit for bit), on
the 2-story building (or ``model``) under a record, with the simulated plant and a
specimen.  The metrics are the review's (:mod:`rths_review.review`, tables 5-9 of
``rths run``'s ``summary.json``, under the same names): the actuator's delay and
tracking error before and after compensation, the 2nd floor's peak and RMS
displacement and their reductions against the uncontrolled building, and the RTHS's
error to the whole-numerical reference.  A run the bridge's safety supervisor stops
has ``safety_stop`` true and no review numbers (NaN), as ``rths run`` reviews none.

The study varies what ``rths run`` takes as options: the record's ``scale``, the
``force_scale`` (DTMs the one in the lab stands for), the ``specimen`` and the sensor
noise; the controllers are the compensation methods (``fir``, the designed filter of
``compensator``, or an adaptive method started from it).  Each run's sensor noise
comes from its own seed.  The identification and design (steps 1-2 of ``rths run``)
are not repeated per run: ``compensator`` names the designed filter (the config's
installed taps, an ``rths run`` output's ``compensator.yaml``, or ``none``).
"""

import functools
import math
import os
from pathlib import Path

import numpy as np

from rths_bringup.commands import default_config_dir
from rths_common import runinfo
from rths_common.params import core_params, renamed
from rths_compensator.methods import DEFAULT as METHOD_DEFAULT
from rths_compensator.methods import METHODS
from rths_compensator.params import PROVENANCE, identity_params
from rths_numerical.ground_motion import RECORDS
from rths_numerical.specimens import SPECIMENS, specimen_settings

from .scenarios import Scenario
from .setting import Setting

#: Settings a study may also vary per run (``rths run``'s options of the same meaning).
VARIED = {'scale': Setting(float, 0.135, minimum=0.0,
                           doc='ground-motion scale factor (rths run --scale)'),
          'force_scale': Setting(float, 5.0, minimum=1e-9,
                                 doc='DTMs the one in the lab stands for (--force-scale)'),
          'specimen': Setting(str, None, choices=SPECIMENS.names(),
                              doc="the specimen (--specimen; default: the config's)"),
          'displacement_noise_m': Setting(float, None, minimum=0.0,
                                          doc="measured displacement noise std [m] (default: "
                                              "the config's)"),
          'force_noise_n': Setting(float, None, minimum=0.0,
                                   doc="measured force noise std [N] (default: the config's)")}
#: The review's numbers kept per run (rths run's summary.json names).
REVIEW = ('delay_ms_before', 'delay_ms_after', 'tracking_rel_rms_pct_before',
          'tracking_rel_rms_pct_after', 'max_disp_2nd_m', 'rms_disp_2nd_m',
          'reduction_max_pct', 'reduction_rms_pct', 'rths_vs_reference_rel_rms_pct',
          'residual_drift_m')
NO_COMPENSATION = 'none'


def _config_dir(value) -> Path:
    return Path(value) if value else default_config_dir()


@functools.lru_cache(maxsize=4)
def _config(config: str, compensator: str):
    """``(numerical, bridge, compensator)`` params of the lab's files (once per process)."""
    folder = _config_dir(config)
    numerical = runinfo.load_params(folder / 'numerical.yaml', 'numerical')
    bridge = renamed(runinfo.load_params(folder / 'bridge.yaml', 'bridge'), 'dtm', 'specimen',
                     str(folder / 'bridge.yaml'))
    fs = float(numerical.get('fs_hz', 1024.0))
    if compensator == NO_COMPENSATION:
        comp = {k: v for k, v in identity_params(fs).items() if k != PROVENANCE}
    else:
        path = folder / 'compensator.yaml' if compensator == 'config' else Path(compensator)
        comp = runinfo.load_params(path, 'compensator')
        provenance = dict(comp.get('provenance') or {})
        if provenance.get('plant'):    # an adaptive method starts from the design's plant
            provenance['plant'] = str((path.parent / str(provenance['plant'])).resolve())
        comp['provenance'] = provenance
    return numerical, bridge, comp


def run_params(settings: dict, run: dict) -> tuple:
    """``(numerical, compensator, bridge)`` params of one run, as ``rths run`` builds them."""
    value = {k: run['params'].get(k, settings[k]) for k in VARIED}
    base_num, base_bridge, comp = _config(settings['config'] or '', settings['compensator'])
    fs = float(base_num.get('fs_hz', 1024.0))
    specimen = value['specimen'] or str(base_bridge.get('specimen') or 'valve4')
    numerical = dict(base_num, model=settings['model'], record=run['record'],
                     scale=value['scale'], force_scale=value['force_scale'],
                     backend='builtin', duration_s=settings['duration_s'],
                     **SPECIMENS[specimen].numerical_params())
    for key in ('sdof_mass_kg', 'sdof_freq_hz', 'sdof_zeta', 'harmonic_freq_hz'):
        numerical.pop(key, None)
    bridge = dict(base_bridge, fs_hz=fs, backend='simulated', specimen=specimen,
                  seed=int(run['seed'] % 2 ** 31),
                  **specimen_settings(specimen, [], 'scenario.specimen'))
    for key in ('displacement_noise_m', 'force_noise_n'):
        if value[key] is not None:
            bridge[key] = value[key]
    method = run['controller'] or METHOD_DEFAULT
    comp = dict(comp, method=method) if method != METHOD_DEFAULT else dict(comp)
    return numerical, comp, bridge


def evaluate_run(settings: dict, run: dict) -> dict:
    """Run one offline RTHS and review it: the metrics of :class:`RthsOfflineScenario`."""
    # `rths` imports every scenario module to list the scenarios in its help
    # lazy: start-up cost: the review loads SciPy and matplotlib (~3 s)
    from rths_bringup.offline import offline_rths
    from rths_numerical.substructure import make_substructure
    from rths_review.review import references, response_metrics, table5_of

    numerical, comp, bridge = run_params(settings, run)
    out = offline_rths(numerical, comp, bridge)
    steps = int(out['steps_run'])
    if np.any(out['safety_state'][:steps] != 0) or not np.all(np.isfinite(out['force'][:steps])):
        return {**{name: math.nan for name in REVIEW}, 'safety_stop': True,
                'steps': float(steps)}
    sub = make_substructure(core_params(numerical))
    fs = 1.0 / sub.dt
    shift = int(core_params(bridge).get('command_delay_steps', 0) or 0)
    desired = out['interface_displacement'][:steps, 0]
    applied = np.concatenate([out['applied'][shift:, 0], np.full(shift, np.nan)])[:steps]
    measured = out['displacement'][:steps, 0]
    ok = np.isfinite(applied) & np.isfinite(measured)
    n = steps if ok.all() else int(np.argmin(ok))
    if n < 2 * fs:
        raise ValueError(f'only {n} steps ran; the review needs at least 2 s '
                         '(scenario.duration_s)')
    desired, applied, measured = desired[:n], applied[:n], measured[:n]
    uncontrolled, reference, _ = references(numerical, bridge, sub, sub.dt)
    ref_disp = reference['disp'][:n] if reference else None
    floor2 = desired - (sub.ug[:n] if sub.frame == 'absolute' else 0.0)
    review = {**table5_of(desired, applied, measured, fs),
              **response_metrics(floor2, ref_disp, uncontrolled['metrics'], fs)}
    return {**{name: math.nan if review[name] is None else float(review[name])
               for name in REVIEW},
            'safety_stop': False, 'steps': float(n)}


class RthsOfflineScenario(Scenario):
    """``rths run``'s RTHS and review, offline (the node cores without ROS), per run."""

    kind = 'rths-offline'
    summary = ("the RTHS main job offline (rths run's cores and review): delay, tracking, "
               'reductions, error to the reference')
    settings = {'config': Setting(str, None, doc='config directory (numerical.yaml, '
                                                 "bridge.yaml; default: the repo's config/)"),
                'compensator': Setting(str, 'config',
                                       doc="the designed filter: config (the config's "
                                           'compensator.yaml), none (identity taps), or a '
                                           "compensator.yaml (rths run's OUT/compensator.yaml)"),
                'model': Setting(str, 'building2story',
                                 doc='numerical model: building2story, sdof or a model YAML'),
                'duration_s': Setting(float, 0.0, minimum=0.0,
                                      doc='simulated seconds (0: the whole record)'),
                **VARIED}
    parameters = dict(VARIED)
    controllers = METHODS.names()
    default_controllers = (METHOD_DEFAULT,)
    uses_records = True
    default_records = ('kobe',)
    metrics = {**{name: 'float' for name in REVIEW}, 'safety_stop': 'bool', 'steps': 'float'}
    chunk = 1

    def check(self, spec):
        """Check the config files, the compensator, the records and the methods."""
        folder = _config_dir(spec.settings['config'])
        for name in ('numerical.yaml', 'bridge.yaml'):
            if not (folder / name).is_file():
                raise ValueError(f'scenario.config: {folder / name} not found; give the '
                                 'directory of the lab\'s params files')
        comp = spec.settings['compensator']
        if comp == 'config' and not (folder / 'compensator.yaml').is_file():
            raise ValueError(f'scenario.compensator: {folder / "compensator.yaml"} not found; '
                             'give a compensator.yaml or none')
        if comp not in ('config', NO_COMPENSATION) and not os.path.isfile(comp):
            raise ValueError(f'scenario.compensator: {comp!r} is not a file, config or none')
        adaptive = [c for c in spec.controllers if c and METHODS.entry(c).adaptive]
        if comp == NO_COMPENSATION and adaptive:
            raise ValueError(f'controllers: {adaptive[0]} needs a designed FIR; with '
                             'scenario.compensator none use fir')
        for i, record in enumerate(spec.records):
            if record not in RECORDS and not os.path.isfile(record):
                raise ValueError(f'records[{i}]: {record!r} is not one of '
                                 f'{", ".join(RECORDS)} nor a record file')

    def evaluate(self, settings, runs):
        """Run and review each run on its own."""
        return [evaluate_run(settings, run) for run in runs]
