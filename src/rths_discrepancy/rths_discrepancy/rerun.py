"""Re-run the reference of an RTHS bag with an updated specimen model (issue 7, the proof).

The RTHS result is the 2nd-floor displacement of the run (the interface
displacement of each step less the ground displacement in the absolute
frame, as in :func:`rths_review.review.review_rths`).  The reference is the
same numerical substructure (same model, record, integrator and step) coupled
in lock-step to a *numerical* DTM on a perfect table
(:func:`rths_numerical.reference.coupled_rths` with a
:class:`rths_numerical.reference.DTMSpecimen`): once with the nominal
specimen model (the run's Table 4 damper, linear) and once with the updated
model, i.e. the nominal one plus the effects the discrepancy workflow named
(``updated_model.yaml``: loop forces such as ``coulomb_friction`` and a
``mass_error``, and ``force_offset``: an offset of the load-cell reading is in the force
the bridge returns to the numerical substructure, so the reference returns the reading
``R + F_0`` too).  The other sensor effects are left out, each with its reason in
the result (:data:`LEFT_OUT`, printed): ``sensor_bias`` offsets the DTM displacement
sensor, which is not in the loop; the specimen scenario's ``time_delay`` is a lag of the
measured specimen channels against the table acceleration that the record does not
place in the load cells or the accelerometer, so the reading returned cannot be rebuilt
from it.  Both references use the same coupling, so the difference between them is the
specimen model alone.

A cache directory (``cache_dir``, ``--reference-cache DIR``) shares the simulations among
the runs of one study: every reference is stored as ``.npy`` under a key of everything it
depends on (the run's numerical parameters, its ground-motion samples, the specimen model,
the frame mass, the integrator), so runs with the same numerical side and nominal specimen
(a benchmark's cases) simulate the nominal and whole-numerical references once.  The key
does not cover this code: use a fresh directory after changing it.

Reported: the relative RMS error [%] (seed Table 9 metric) of the RTHS
against each reference, and against the linear whole-numerical reference of
seed 6.3.4 (:func:`rths_numerical.reference.simulate_reference`) that
``rths review`` prints.

The run's parameters come from the bag's run information
(:mod:`rths_common.runinfo`: ``rths launch --bag`` and ``rths run`` store
the numerical and bridge parameters in the bag).  Only a bag whose run
information lacks them (a recorder started by hand) needs the params
directory of its launch (``--config DIR``: numerical.yaml and bridge.yaml).
"""

import hashlib
import json
import os
from pathlib import Path

import numpy as np

from rths_common import bagio, runinfo, topics
from rths_common.params import core_params
from rths_discrepancy import effects as fx
from rths_discrepancy import models
from rths_numerical.dtm import FRAME_MASS_KG, DTMParameters
from rths_numerical.reference import (
    DTMSpecimen,
    coupled_rths,
    relative_rms_error,
    simulate_reference,
)
from rths_numerical.specimens import SPECIMENS, specimen_of
from rths_numerical.substructure import make_substructure

#: Sub-steps per sample of the DTM integration when the model has a non-linear force.
SUBSTEPS = 16

#: Effects of an updated specimen model that the reference leaves out, and why.
LEFT_OUT = {
    'sensor_bias': 'an offset of the DTM displacement sensor: the bridge returns the '
                   'load-cell force, so it changes what is measured, not the RTHS',
    'time_delay': 'a lag of the measured specimen channels against the table acceleration; '
                  'the record does not tell whether the load cells or the accelerometer lag, '
                  'so the force the bridge returned cannot be rebuilt from it',
}


def run_parameters(bag, config=None) -> tuple:
    """``(numerical, bridge)`` parameters of the run of ``bag``.

    From the bag's run information when it has them (``rths launch --bag``,
    ``rths run``), else from the params files in ``config`` (the directory
    the run was launched with).
    ValueError names the fix when neither is available.
    """
    info = bagio.run_info(bag)
    numerical = runinfo.section(info, 'numerical')
    bridge = runinfo.section(info, 'bridge')
    if not numerical and config is not None:
        cfg = Path(config)
        numerical = runinfo.load_params(cfg / 'numerical.yaml', 'numerical')
        bridge = runinfo.load_params(cfg / 'bridge.yaml', 'bridge')
    if not numerical:
        raise ValueError(f"{bag}: the bag's run information has no numerical parameters "
                         '(recorder started without them?); '
                         'pass --config DIR, the params directory the run was launched with '
                         '(numerical.yaml, bridge.yaml)')
    return core_params(numerical), core_params(bridge)


def has_table_mass(bridge: dict) -> bool:
    """Return True if the run's ``specimen`` is a mass on the table (a DTM, eq. 46)."""
    return SPECIMENS.entry(specimen_of(bridge), "the run's bridge parameter").table_mass \
        is not None


def run_damper_model(bridge: dict) -> models.SpecimenModel:
    """Nominal specimen model of a run: the mass on the table of the bridge's ``specimen``."""
    name = specimen_of(bridge)
    p = SPECIMENS.entry(name, "the run's bridge parameter").table_mass
    if p is None:
        key = 'specimen' if 'specimen' in bridge else 'dtm'
        raise ValueError(f"the run's bridge has {key}: {name}, no mass on the table; there is "
                         'no specimen to review (the specimen scenario reviews a DTM, eq. 46)')
    return models.SpecimenModel(p.m_d, p.c_d, p.k_d)


class LoadCellReading:
    """A specimen of the reference whose load-cell reading is offset: ``R + F_0``.

    ``F_0`` is the library's ``force_offset`` (an offset of the reading, the force the
    bridge returns to the numerical substructure; :mod:`.effects`).
    """

    def __init__(self, specimen, offset_n: float):
        """Wrap ``specimen`` (table displacement -> ``[R]``) with the reading offset [N]."""
        self.specimen = specimen
        self.offset_n = float(offset_n)

    def __call__(self, table_disp):
        """Return ``[R + F_0]`` [N] for this step's table displacement [m]."""
        return self.specimen(table_disp) + self.offset_n


def specimen(model: models.SpecimenModel, dt: float, frame_mass_kg=None):
    """Return the reference's specimen simulating ``model``'s effects (but :data:`LEFT_OUT`).

    A :class:`rths_numerical.reference.DTMSpecimen` with the loop forces and the mass
    error, read through :class:`LoadCellReading` when the model has a ``force_offset``.
    """
    loop = {k: v for k, v in model.effects.items()
            if k not in ('force_offset', 'mass_error', *LEFT_OUT)}
    force = fx.specimen_force(loop, model) if loop else None
    frame = FRAME_MASS_KG if frame_mass_kg is None else float(frame_mass_kg)
    dtm = DTMSpecimen(DTMParameters(model.m_d, model.c_d, model.k_d), dt, frame, force=force,
                      mass_error=model.effects.get('mass_error', 0.0), substeps=SUBSTEPS)
    offset = model.effects.get('force_offset', 0.0)
    return LoadCellReading(dtm, offset) if offset else dtm


def left_out(model: models.SpecimenModel) -> dict:
    """Return {effect: reason} for the effects of ``model`` the reference leaves out."""
    return {k: LEFT_OUT[k] for k in model.effects if k in LEFT_OUT}


def _frame_mass(bridge):
    val = bridge.get('frame_mass_kg')
    try:
        val = float(val)
    except (TypeError, ValueError):
        return None
    return val if np.isfinite(val) else None


def rths_floor_displacement(bag, sub) -> np.ndarray:
    """2nd-floor displacement [m] (relative to the ground) of the RTHS recorded in ``bag``."""
    disp = bagio.step_arrays(bag, topics.INTERFACE_DISPLACEMENT, ('displacement',))
    desired = _whole_steps(disp['step'], disp['displacement'][:, 0], bag)
    n = desired.size
    ok = np.isfinite(desired)
    if not ok.all():
        n = int(np.argmin(ok))
        desired = desired[:n]
    n = min(n, sub.n_steps)
    ug = sub.ug[:n] if sub.frame == 'absolute' else 0.0
    return desired[:n] - ug


#: Steps a recorder may have lost (a loaded machine) that are filled linearly: at most this
#: fraction of the run, and no gap longer than ``MAX_GAP_STEPS``.
MAX_FILLED_FRACTION = 0.02
MAX_GAP_STEPS = 64


def _whole_steps(steps, values, bag) -> np.ndarray:
    """Return ``values`` indexed by step 0..last, short recording gaps filled linearly."""
    steps = np.asarray(steps, dtype=np.int64)
    if steps.size == 0:
        raise ValueError(f'{bag}: no interface-displacement messages recorded')
    steps, first = np.unique(steps, return_index=True)
    values = np.asarray(values, float)[first]
    whole = np.arange(int(steps[-1]) + 1)
    missing = np.setdiff1d(whole, steps)
    gaps = np.diff(steps) - 1
    if missing.size > MAX_FILLED_FRACTION * whole.size or (gaps.size and gaps.max()
                                                           > MAX_GAP_STEPS) or steps[0] != 0:
        raise ValueError(f'{bag}: {missing.size} interface-displacement steps are missing '
                         f'(longest gap {int(gaps.max()) if gaps.size else 0}); more than '
                         'the recording gaps this comparison fills (2 %, 64 steps each)')
    return np.interp(whole, steps, values) if missing.size else values


def _cached(cache_dir, hits, label, key, compute) -> np.ndarray:
    """Return ``compute()``, stored in ``cache_dir`` under the hash of ``key`` (None: no cache)."""
    if cache_dir is None:
        return compute()
    digest = hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode()).hexdigest()
    path = Path(cache_dir) / f'{label}-{digest[:32]}.npy'
    if path.is_file():
        hits.append(label)
        return np.load(path)
    values = np.asarray(compute(), dtype=float)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f'{path.stem}.{os.getpid()}.tmp.npy')
    np.save(tmp, values)
    os.replace(tmp, path)
    return values


def compare(bag, updated_model, config=None, nominal_model=None, progress=None,
            cache_dir=None, updated_only=False) -> dict:
    """RTHS-vs-reference relative RMS error [%] with the nominal and the updated specimen model.

    ``updated_model`` is a :class:`.models.SpecimenModel` or a YAML path;
    ``nominal_model`` defaults to the run's Table 4 damper.  ``progress(done, 3)``
    follows the three simulations (nominal, updated, whole numerical); ``cache_dir``
    shares them among runs (module docstring).  ``updated_only``: simulate only the
    reference with the updated model (``rths review --specimen-model``); the result then
    has no nominal and whole-numerical figures.
    """
    numerical, bridge = run_parameters(bag, config)
    if not isinstance(updated_model, models.SpecimenModel):
        updated_model = models.load_model('specimen', updated_model)
    nominal = nominal_model or run_damper_model(bridge)
    sub = make_substructure(numerical)
    if sub.iface != [sub.model.output_dof]:
        raise ValueError('the comparison needs the output DOF to be the interface DOF')
    floor2 = rths_floor_displacement(bag, sub)
    n = floor2.size
    if n < 2:
        raise ValueError(f'{bag}: fewer than 2 steps recorded')
    frame = _frame_mass(bridge)
    out = {'bag': str(bag), 'steps': n, 'duration_s': n * sub.dt,
           'nominal_model': nominal.to_dict(), 'updated_model': updated_model.to_dict(),
           'left_out_of_reference': left_out(updated_model)}
    hits = []
    side = {'numerical': numerical, 'frame_mass_kg': frame, 'dt': sub.dt,
            'ground_motion_sha256': hashlib.sha256(
                np.ascontiguousarray(sub.ag, dtype=float).tobytes()).hexdigest()}
    refs = {}
    pairs = (('nominal', nominal), ('updated', updated_model))
    for k, (label, model) in enumerate(pairs[1:] if updated_only else pairs):
        if progress:
            progress(k, 3)
        refs[label] = _cached(
            cache_dir, hits, 'coupled', {**side, 'specimen': model.to_dict(),
                                         'substeps': SUBSTEPS},
            lambda m=model: coupled_rths(make_substructure(numerical),
                                         specimen(m, sub.dt, frame))['output_disp'])[:n]
        out[f'rths_vs_{label}_reference_rel_rms_pct'] = relative_rms_error(floor2, refs[label])
        out[f'{label}_reference_max_disp_2nd_m'] = float(np.max(np.abs(refs[label])))
    if updated_only:
        out['_series'] = {'rths': floor2, **refs}
        return out
    if progress:
        progress(2, 3)
    whole = _cached(
        cache_dir, hits, 'whole', {**side, 'damper': nominal.to_dict()},
        lambda: simulate_reference(sub.model, sub.ag, sub.dt, damper=_params(nominal),
                                   n_dtm=sub.force_scale, frame_mass_kg=frame or FRAME_MASS_KG,
                                   integrator=numerical.get('integrator', 'cr'))['disp'])
    out['rths_vs_linear_whole_numerical_rel_rms_pct'] = relative_rms_error(floor2, whole[:n])
    if cache_dir is not None:
        out['reference_cache'] = {'dir': str(cache_dir), 'reused': hits}
    if progress:
        progress(3, 3)
    out['rths_max_disp_2nd_m'] = float(np.max(np.abs(floor2)))
    before = out['rths_vs_nominal_reference_rel_rms_pct']
    after = out['rths_vs_updated_reference_rel_rms_pct']
    out['error_ratio_after_before'] = after / before if before > 0 else float('nan')
    out['_series'] = {'rths': floor2, **refs}
    return out


def _params(model):
    return DTMParameters(model.m_d, model.c_d, model.k_d)


def summary_lines(res: dict) -> list:
    """Return the printed lines of :func:`compare`."""
    eff = res['updated_model'].get('effects', {})
    names = ', '.join(f'{k} {v:.4g}' for k, v in eff.items()) or 'no effects'
    return [
        f"RTHS vs reference (2nd-floor displacement, {res['steps']} steps, "
        f"{res['duration_s']:.1f} s), relative RMS error:",
        '  nominal specimen model (linear DTM):  '
        f"{res['rths_vs_nominal_reference_rel_rms_pct']:.3f} %",
        f"  updated specimen model ({names}):  "
        f"{res['rths_vs_updated_reference_rel_rms_pct']:.3f} %",
        f"  (linear whole-numerical reference, seed 6.3.4: "
        f"{res['rths_vs_linear_whole_numerical_rel_rms_pct']:.3f} %)",
    ] + [f'  left out of the updated reference: {k}: {why}'
         for k, why in res.get('left_out_of_reference', {}).items()]


REPORT_HEADING = '## The RTHS re-run with the updated model'


def report_section(res: dict) -> str:
    """Return the report.md section of :func:`compare`: RTHS-vs-reference before and after."""
    lines = [REPORT_HEADING, '',
             'The reference of the RTHS run (its numerical substructure coupled in lock-step to '
             'the specimen model on a perfect actuator) re-run with the nominal and with the '
             'updated specimen model (`rths reference BAG --specimen-model updated_model.yaml`; '
             '`rths review BAG --specimen-model` puts it in the review). Relative RMS error of '
             'the 2nd-floor displacement (seed Table 9 metric):', '',
             '| reference | RTHS vs reference [%] |', '|---|---|']
    lines += [f'| {line.split(":")[0].strip()} | {line.rsplit(":", 1)[1].strip()} |'
              for line in summary_lines(res)[1:3]]
    lines += ['', f"(linear whole-numerical reference, seed 6.3.4: "
              f"{res['rths_vs_linear_whole_numerical_rel_rms_pct']:.3f} %; plot: "
              'reference.png)', '']
    lines += [f'Left out of the updated reference: `{k}`: {why}.'
              for k, why in res.get('left_out_of_reference', {}).items()]
    if res.get('left_out_of_reference'):
        lines.append('')
    return '\n'.join(lines)


def write(res: dict, path) -> None:
    """Write :func:`compare`'s result (without the time series) as JSON, atomically."""
    data = {k: v for k, v in res.items() if not k.startswith('_')}
    tmp = f'{path}.tmp'
    with open(tmp, 'w') as fh:
        json.dump(data, fh, indent=2)
    os.replace(tmp, path)


def plot(res: dict, path) -> None:
    """Time history of the RTHS and both references and the two differences (PNG)."""
    # lazy: start-up cost: matplotlib (~0.5 s), which this module needs only here
    import matplotlib
    matplotlib.use('Agg')
    # lazy: start-up cost: matplotlib (~0.5 s), which this module needs only here
    import matplotlib.pyplot as plt
    s = res['_series']
    t = np.arange(s['rths'].size) * res['duration_s'] / max(s['rths'].size, 1)
    fig, ax = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    ax[0].plot(t, s['rths'] * 1e3, lw=1.0, label='RTHS')
    ax[0].plot(t, s['nominal'] * 1e3, lw=0.8, label='reference, nominal specimen')
    ax[0].plot(t, s['updated'] * 1e3, '--', lw=0.8, label='reference, updated specimen')
    ax[0].set_ylabel('2nd-floor displacement [mm]')
    ax[0].legend(fontsize=8, loc='upper right')
    ax[1].plot(t, (s['rths'] - s['nominal']) * 1e3, lw=0.7, label='RTHS - nominal')
    ax[1].plot(t, (s['rths'] - s['updated']) * 1e3, lw=0.7, label='RTHS - updated')
    ax[1].set_ylabel('difference [mm]')
    ax[1].set_xlabel('time [s]')
    ax[1].legend(fontsize=8, loc='upper right')
    fig.tight_layout()
    tmp = f'{path}.tmp.png'
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    os.replace(tmp, path)
