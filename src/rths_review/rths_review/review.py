"""Review of a recorded run, rebuilt from its bag alone.

A realtime run recorded over DDS (processes layout) may hold a step twice (the
numerical node re-sends step 0 until the loop runs) or lack some (a recorder
that fell more than the writers' history behind the loop):
:func:`rths_review.tracking.aligned_steps` drops identical re-sends and fills the
gaps linearly (the spectral delay estimate needs an unbroken series); the review
is written anyway and says how complete the recording is: ``recording_complete``
and every gap (topic, first step, length, time) in summary.json, review.txt and
report.html, and the tracking errors of Table 5 are computed on the recorded
steps only.  A run stopped before the end of its record (a safety stop, a killed
launcher) is reviewed up to where it stopped and said to be cut short; a realtime
run's timing is judged by :mod:`rths_review.realtime`.  A run of several actuators
(a rig file) is reviewed per actuator and interface DOF by :mod:`rths_review.actuators`.
"""

import json
from pathlib import Path

import numpy as np

from rths_actuator_bridge.bridge import DEFAULT_BACKEND, backend_class
from rths_common import bagio, runinfo, topics
from rths_common.params import core_params
from rths_numerical.inputs import parse_inputs, table_from_chunks
from rths_numerical.model import LinearModel
from rths_numerical.reference import (
    coupled_rths,
    metrics,
    relative_rms_error,
    simulate_reference,
    simulate_uncontrolled,
)
from rths_numerical.specimens import SPECIMENS, specimen_of
from rths_numerical.substructure import make_substructure
from rths_review import plots
from rths_review.actuators import actuators_text, review_actuators
from rths_review.report_html import notes, row_label, specimen_title, write_report
from rths_review.tracking import (
    REVIEW_STAGES,
    STEP_TOPICS,
    bridge_realtime,
    controller_counts,
    read_loop,
    recording_summary,
    run_account,
    step_check,
    table5_of,
    tracking_channels,
)


def _pct(values, q):
    values = [v for v in values if v >= 0]
    return round(float(np.percentile(values, q)), 1) if values else None


def loop_summary(bag) -> dict:
    """Return the printed/JSON summary of a run: steps per topic, extremes, per-node timing."""
    loop = read_loop(bag)
    summary = {'bag': str(bag)}
    for topic, (field, unit) in STEP_TOPICS.items():
        entry = step_check(loop['steps'][topic]['step'])
        values = loop['steps'][topic]['values']
        if values:
            entry[f'max_abs_{field}_{unit}'] = float(np.max(np.abs(np.concatenate(values))))
        summary[topic] = entry
    for node, s in sorted(loop['status'].items()):
        summary[f'status {node}'] = {
            'steps': len(s['step']),
            'compute_us_p50': _pct(s['compute_us'], 50),
            'compute_us_p99': _pct(s['compute_us'], 99),
            'latency_us_p50': _pct(s['latency_us'], 50),
            'latency_us_p99': _pct(s['latency_us'], 99),
            'deadline_misses': s['misses'],
            'final_safety_state': s['safety_state'][-1] if s['safety_state'] else None,
            'faults': s['faults'][:5],
        }
    return summary


# ---------------------------------------------------------------------------------------------
# The RTHS review (step 4 of rths run; rths review BAG)


#: ``specimen`` of a run through a servo controller (a backend outside the bridge process).
EXTERNAL = 'external controller'


def external_controller(bridge: dict) -> str:
    """Return ``'external controller HOST:PORT'`` for a run through a servo controller, else ''.

    Any backend whose plant does not live in the bridge's process drives a lab's actuator
    and specimen through its controller: the review has no model of them.
    """
    try:
        in_process = backend_class(bridge).in_process
    except ValueError:       # a backend this installation does not know: not in the process
        in_process = False
    if in_process:
        return ''
    return f"{EXTERNAL} {bridge.get('host', '?')}:{bridge.get('port', '?')}"


def controller_text(c: dict) -> str:
    """One line of an external controller's counts (review text and report)."""
    text = (f"controller {c['address']} (protocol version {c['protocol_version']}): "
            f"replies lost {c['replies_lost']}, late {c['replies_late']}, malformed "
            f"{c['replies_malformed']}, restarts {c['restarts']}, worst reply "
            f"{c['worst_reply_ms']:.3f} ms ({c['replies']} used)")
    return text + (f"; fault: {c['fault']}" if c.get('fault') else '')


def _numerical_params(info: dict) -> dict:
    """Return the run's numerical core parameters (node-level keys stripped, as offline does)."""
    return core_params(runinfo.section(info, 'numerical'))


def _tracking(bag, fs):
    """Return :func:`rths_review.tracking.tracking_channels` of the one actuator (1-D)."""
    desired, applied, measured, *rest = tracking_channels(bag, fs, channels=1)
    return (desired[:, 0], applied[:, 0], measured[:, 0], *rest)


def run_inputs(bag, numerical: dict):
    """Return the run's substructure, from the bag's own copy of its model and record.

    Bags recorded before the copy existed rebuild it from the files the parameters name.
    """
    recorded = bagio.read_topic(bag, topics.RUN_INPUTS)
    if not recorded:
        return make_substructure(numerical)
    model, motion, _ = parse_inputs(recorded[-1][1].data)
    return make_substructure(numerical, model, motion)


def response_of(bag):
    """Return ``(columns, table)`` of the bag's /rths/response (None, None if absent)."""
    return table_from_chunks((m.layout.data_offset, m.data, m.layout.dim[1].label)
                             for _, m in bagio.read_topic(bag, topics.RESPONSE))


def dof_index(model, dof, where: str = '--dof') -> int:
    """Return the index of DOF ``dof`` (a name of the model, or a number from 1)."""
    names = list(getattr(model, 'dof_names', []) or [])
    text = str(dof).strip()
    if text in names:
        return names.index(text)
    if text.isdigit() and 1 <= int(text) <= model.n:
        return int(text) - 1
    raise ValueError(f'{where} {dof}: the model {getattr(model, "name", "")} has no such DOF; '
                     f'give one of {", ".join(names)} or a number 1..{model.n}')


def review_rths(bag, out_dir, progress=None, limits=None, specimen_model=None,
                dof=None) -> dict:
    """Tables 5-9 of an RTHS bag: JSON summary, text report, PNG plots and ``report.html``.

    ``specimen_model``: an updated specimen model (``updated_model.yaml`` of ``rths
    discrepancy --scenario specimen``) for the Table 9 reference instead of the run's
    nominal specimen: the same substructure coupled in lock-step to that model on a
    perfect actuator (:func:`rths_discrepancy.rerun.compare`); the summary names it
    (``reference_model``).  Refused for a run whose specimen is no mass on the table.

    ``report.html`` (:mod:`rths_review.report_html`) holds the tables and every
    plot in one self-contained file.  ``progress(done, 4)`` follows the stages: bag
    read, references simulated, plots drawn, report written.  ``dof``: the DOF
    the tables report (a name of the model or a number from 1; default the model's
    output DOF).  The model and the record come from the bag (:func:`run_inputs`).
    ``limits``: the real-time limits a realtime run is judged by
    (:mod:`rths_review.realtime`).
    """
    stage = progress or (lambda done, total: None)

    bag, out_dir = Path(bag), Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    info = bagio.run_info(bag)
    if info.get('kind') != 'rths':
        raise ValueError(f'{bag}: not an RTHS run bag (run information kind = '
                         f'{info.get("kind")!r}); record it with rths run')
    fs = bagio.sampling_rate(bag)
    numerical = _numerical_params(info)
    if not numerical:   # rths site: the model ran in the client (OpenSees), table 5 only
        return review_site(bag, out_dir, info, fs, stage)
    bridge = runinfo.section(info, 'bridge')
    compensator = runinfo.section(info, 'compensator')
    sub = run_inputs(bag, numerical)
    if getattr(sub, 'n_interface', 1) > 1 and getattr(sub, 'model', None) is None:
        if specimen_model is not None or dof is not None:
            raise ValueError(f'{bag}: a run of {sub.n_interface} actuators: its review is per '
                             'actuator and interface DOF; drop --specimen-model and --dof')
        return review_actuators(bag, out_dir, info, fs, sub, stage, limits)
    model = sub.model
    if dof is not None:
        model.output_dof = dof_index(model, dof)
    columns, response = response_of(bag)
    if sub.iface != [model.output_dof] and response is None:
        raise ValueError(f'{bag}: the bag has no /rths/response (recorded before it existed), '
                         'so only the interface DOF can be reviewed; drop --dof')

    desired, applied, measured, meas, status, n, recorded, recording, kept = _tracking(bag, fs)
    timing = bridge_realtime(status, sub.n_steps, fs, limits) if (
        info.get('mode') == 'realtime') else None
    stage(1, REVIEW_STAGES)

    table5 = table5_of(desired, applied, measured, fs, kept)
    # Tables 6-9: the 2nd floor relative to the ground
    ug = sub.ug[:n] if sub.frame == 'absolute' else 0.0
    floor2 = (desired - ug if sub.iface == [model.output_dof]
              else response[:n, 2 + model.output_dof])
    dt = 1.0 / fs
    name = specimen_of(bridge)
    remote = bridge.get('backend') == 'genericclient'
    external = '' if remote else external_controller(bridge)
    if remote:   # a remote site: no model of its specimen (compared with the bare building)
        name, bridge = 'remote', dict(bridge, specimen='none')

    def build():
        own = run_inputs(bag, numerical)
        own.model.output_dof = model.output_dof     # the DOF the review reports
        return own
    uncontrolled, reference, specimen = references(numerical, bridge, sub, dt,
                                                   specimen_known=not external,
                                                   where=f'{bag}: bridge parameter specimen',
                                                   build=build)
    reference_model = 'nominal specimen model (the run\'s specimen, linear)'
    if specimen_model is not None:
        reference, reference_model = _updated_reference(bag, specimen, specimen_model)
    if external:
        ref_disp = None
    else:
        ref_disp = reference['disp'][:n] if reference else uncontrolled['disp'][:n]
    stage(2, REVIEW_STAGES)
    summary = {
        'record': numerical.get('record'), 'scale': numerical.get('scale'),
        # damper: the former name of the key
        'specimen': EXTERNAL if external else name, 'damper': EXTERNAL if external else name,
        'specimen_label': external or name,
        'mode': info.get('mode'), 'fs_hz': fs, 'steps': n, 'duration_s': n * dt,
        'compensator': compensator,
        'numerical_backend': numerical.get('backend', 'builtin'),
        'numerical_model': getattr(model, 'name', str(numerical.get('model'))),
        # loop steps per numerical step (rths_numerical.multirate; 1: every loop step)
        'numerical_rate_divisor': int(getattr(sub, 'divisor', 1)),
        'force_scale': float(sub.force_scale), 'interface_frame': sub.frame,
        'input_processing': list(sub.motion.processing) if sub.motion is not None else [],
        'record_summary': sub.motion.summary() if sub.motion is not None else None,
        'dof': _dof_name(model, model.output_dof),
        'interface_dofs': [_dof_name(model, i) for i in sub.iface],
        'every_dof': _every_dof(model, columns, response, n),
        **table5,
        **response_metrics(floor2, ref_disp, uncontrolled['metrics'], fs),
        'reference_model': reference_model if ref_disp is not None else None,
        **run_account(bag, status, sub.n_steps, recorded, recording, kept, timing),
    }
    (out_dir / 'summary.json').write_text(json.dumps(summary, indent=2))
    (out_dir / 'review.txt').write_text(review_text(summary))
    plots.review_plots(out_dir, fs, desired, applied, measured, floor2, ref_disp,
                       uncontrolled['disp'][:n])
    hinge = _hinge_history(bag, reference)
    if hinge is not None:
        plots.hysteresis_plot(out_dir / 'hinge_hysteresis.png', hinge['hinge_rotation'],
                              hinge['hinge_moment'], fs, f"hinge of {summary['numerical_model']} "
                              f"({hinge['source']})", ('rotation [mrad]', 'moment [N m]'),
                              velocity=False)
    if specimen is not None and specimen.params:
        summary.update(specimen.settings(bridge))
        (out_dir / 'summary.json').write_text(json.dumps(summary, indent=2))
    if specimen is not None and specimen.hysteresis:
        settings = ', '.join(f'{k} {v:g}' for k, v in specimen.settings(bridge).items())
        plots.hysteresis_plot(out_dir / plots.HYSTERESIS_PNG, measured, meas['force'][:n, 0],
                              fs, f'specimen {name} ({settings}), measured')
    stage(3, REVIEW_STAGES)
    write_report(out_dir, summary)
    stage(4, REVIEW_STAGES)
    return summary


def references(numerical, bridge, sub, dt, specimen_known=True, where='bridge specimen',
               build=None):
    """``(uncontrolled, reference, specimen)`` responses of a run's substructure ``sub``.

    ``uncontrolled``: the building without the specimen; ``reference``: the whole-numerical
    RTHS (the same substructure with the specimen model on a perfect actuator), None where
    there is no model of the specimen (``specimen_known`` False: a lab's own controller; a
    bare table).  Both are dicts with ``disp`` and ``metrics``.  ``build``: returns a fresh
    copy of ``sub`` for the offline runs (default: built again from ``numerical``).
    """
    model = sub.model
    uncontrolled = (simulate_uncontrolled(model, sub.ag, dt, numerical.get('integrator', 'cr'))
                    if isinstance(model, LinearModel) else None)
    backend = numerical.get('backend', 'builtin')
    specimen = SPECIMENS.entry(specimen_of(bridge), where) if specimen_known else None
    if specimen is None:   # no model of the lab's specimen: no reference to compare with
        if uncontrolled is None:
            uncontrolled, _ = offline_references(numerical, dict(bridge, specimen='none'), dt,
                                                 build)
        reference = None
    elif specimen.device is not None or backend != 'builtin':
        # a device specimen or an OpenSees model: the same substructure, offline, with the
        # same specimen model on a perfect actuator (and without it for the uncontrolled one)
        uncontrolled, reference = offline_references(numerical, bridge, dt, build)
    elif specimen.mass_on_table(bridge) is not None:
        reference = simulate_reference(model, sub.ag, dt, damper=specimen.mass_on_table(bridge),
                                       n_dtm=sub.force_scale,
                                       frame_mass_kg=specimen.frame_mass(bridge),
                                       integrator=numerical.get('integrator', 'cr'),
                                       uncontrolled=uncontrolled)
    else:
        reference = None
    return uncontrolled, reference, specimen


def response_metrics(floor2, ref_disp, uncontrolled: dict, fs) -> dict:
    """Tables 6-9: the 2nd floor's response, its reductions and its error to the reference.

    ``floor2``: the RTHS 2nd-floor displacement relative to the ground [m];
    ``ref_disp``: the reference's (None: no reference); ``uncontrolled``: the
    uncontrolled building's ``metrics`` (``max_disp_m``, ``rms_disp_m``).
    """
    max_d, rms_d = float(np.max(np.abs(floor2))), float(np.sqrt(np.mean(floor2 ** 2)))
    return {
        'residual_drift_m': residual_drift(floor2, fs),
        'reference_residual_drift_m': _or_none(ref_disp, lambda r: residual_drift(r, fs)),
        'max_disp_2nd_m': max_d, 'rms_disp_2nd_m': rms_d,
        'uncontrolled_max_disp_2nd_m': uncontrolled['max_disp_m'],
        'uncontrolled_rms_disp_2nd_m': uncontrolled['rms_disp_m'],
        'reduction_max_pct': 100 * (1 - max_d / uncontrolled['max_disp_m']),
        'reduction_rms_pct': 100 * (1 - rms_d / uncontrolled['rms_disp_m']),
        'reference_max_disp_2nd_m': _or_none(ref_disp, lambda r: float(np.max(np.abs(r)))),
        'reference_rms_disp_2nd_m': _or_none(ref_disp,
                                             lambda r: float(np.sqrt(np.mean(r ** 2)))),
        'rths_vs_reference_rel_rms_pct': _or_none(ref_disp,
                                                  lambda r: relative_rms_error(floor2, r)),
    }


def _or_none(value, f):
    return None if value is None else f(value)


def review_site(bag, out_dir, info, fs, stage) -> dict:
    """Review a ``rths site`` run: table 5 and the tracking plots (the model was the client's).

    Tables 6-9 need the numerical model, which ran in the client (OpenSees,
    OpenFresco): the bag holds none, so they are left out rather than guessed.
    """
    desired, applied, measured, meas, status, n, recorded, recording, kept = _tracking(bag, fs)
    stage(1, REVIEW_STAGES)
    bridge = runinfo.section(info, 'bridge')
    summary = {
        'kind': 'site', 'mode': info.get('mode'), 'fs_hz': fs, 'steps': n,
        'duration_s': n / fs,
        'backend': bridge.get('backend', DEFAULT_BACKEND),
        'specimen': bridge.get('specimen', bridge.get('dtm', '-')),   # as the site's file says
        'compensator': runinfo.section(info, 'compensator'),
        **table5_of(desired, applied, measured, fs, kept),
        'deadline_misses': int(status.get('misses', 0)),
        'deadline_miss_pct': 100.0 * status.get('misses', 0)
        / max(len(status.get('step', [])), 1),
        'safety_faults': status.get('faults', []),
        **recording_summary(recording, kept),
        'site_events': [f.split(': ', 1)[1] for f in  # drop the 'step 0: ' prefix
                        read_loop(bag)['status'].get('site', {}).get('faults', [])],
    }
    counts = controller_counts(bag)
    if counts is not None:    # the site's own actuator through a servo controller
        summary['controller'] = counts
    stage(2, REVIEW_STAGES)
    out_dir = Path(out_dir)
    (out_dir / 'summary.json').write_text(json.dumps(summary, indent=2))
    (out_dir / 'review.txt').write_text(review_text(summary))
    plots.tracking_plots(out_dir, fs, desired, applied, measured)
    stage(3, REVIEW_STAGES)
    write_report(out_dir, summary)
    stage(4, REVIEW_STAGES)
    return summary


def _updated_reference(bag, specimen, path):
    """Return ``(reference, label)``: the lock-step reference with the specimen model ``path``."""
    # lazy: start-up cost: the discrepancy package (SciPy optimisers), needed only here
    from rths_discrepancy import models, rerun

    if specimen is None or specimen.table_mass is None:
        raise ValueError(f'--specimen-model {path}: the run\'s specimen is no mass on the '
                         'table; an updated DTM model does not apply to it')
    updated = models.load_model('specimen', path)
    cmp = rerun.compare(bag, updated, updated_only=True)
    effects = ', '.join(f'{k} {v:.4g}' for k, v in updated.effects.items()) or 'no effects'
    left = ''.join(f'; {k} left out: {why}' for k, why in cmp['left_out_of_reference'].items())
    return ({'disp': cmp['_series']['updated']},
            f'updated specimen model {path} ({effects}; lock-step reference, perfect actuator'
            f'{left})')


def _site_text(s: dict) -> str:
    lines = [
        f"Site review (rths site): backend {s['backend']}, "
        f"specimen {s['specimen']}, {s['mode']}, {s['steps']} steps at {s['fs_hz']:g} Hz "
        f"({s['duration_s']:.1f} s)", '',
        'Table 5 layout: actuator time delay and relative RMS tracking error',
        '                      before compensation   after compensation',
        f"  time delay [ms]     {s['delay_ms_before']:>19.3f}   {s['delay_ms_after']:>18.3f}",
        f"  rel. RMS error [%]  {s['tracking_rel_rms_pct_before']:>19.2f}   "
        f"{s['tracking_rel_rms_pct_after']:>18.2f}",
        '  (before: plant input -> output; after: trial displacement -> output)', '',
        'Tables 6-9 need the numerical model, which ran in the client: not part of a site '
        'review.']
    lines += [f'site: {e}' for e in s['site_events']]
    if s['safety_faults']:
        lines.append('safety faults: ' + '; '.join(s['safety_faults']))
    return '\n'.join(lines) + '\n'


def _dof_name(model, i: int) -> str:
    names = list(getattr(model, 'dof_names', []) or [])
    return names[i] if i < len(names) else f'dof{i + 1}'


def _every_dof(model, columns, response, n) -> list:
    """Return max and RMS of every DOF's relative displacement in the RTHS [m]."""
    if response is None:
        return []
    rows = []
    for j in range(2, len(columns)):
        d = response[:n, j]
        rows.append({'dof': _dof_name(model, j - 2), 'column': columns[j],
                     'max_m': float(np.max(np.abs(d))), 'rms_m': float(np.sqrt(np.mean(d ** 2)))})
    return rows


def review_text(s: dict) -> str:
    """Return the review as text, in the layout of the seed's tables 5-9."""
    if s.get('kind') == 'site':
        return _site_text(s)
    if s.get('kind') == 'actuators':
        return actuators_text(s)
    inch = 0.0254
    lines = [
        f"RTHS review: {s['record']} x {s['scale']}, specimen {specimen_title(s)}, {s['mode']}, "
        f"{s['steps']} steps at {s['fs_hz']:g} Hz ({s['duration_s']:.1f} s)",
        f"  model {s['numerical_model']}, force scale {s.get('force_scale', '?')}, interface "
        f"frame {s.get('interface_frame', '?')} at {', '.join(s.get('interface_dofs', []))}",
        '  input processing: ' + ('; '.join(s.get('input_processing') or []) or 'none'),
        '',
        'Table 5 layout: actuator time delay and relative RMS tracking error',
        '                      before compensation   after compensation',
        f"  time delay [ms]     {s['delay_ms_before']:>19.3f}   {s['delay_ms_after']:>18.3f}",
        f"  rel. RMS error [%]  {s['tracking_rel_rms_pct_before']:>19.2f}   "
        f"{s['tracking_rel_rms_pct_after']:>18.2f}",
        '  (before: plant input -> output; after: interface displacement -> output)',
        '',
        f"Tables 6-8 layout: displacement of {s.get('dof', 'the output DOF')} (relative)",
        '  model            max [m]      max [in]   red. [%]   RMS [m]      RMS [in]   red. [%]',
        f"  uncontrolled     {s['uncontrolled_max_disp_2nd_m']:.4e}  "
        f"{s['uncontrolled_max_disp_2nd_m'] / inch:8.4f}        -     "
        f"{s['uncontrolled_rms_disp_2nd_m']:.4e}  {s['uncontrolled_rms_disp_2nd_m'] / inch:8.4f}"
        '        -',
        f"  RTHS ({row_label(s)})".ljust(19) + f"{s['max_disp_2nd_m']:.4e}  "
        f"{s['max_disp_2nd_m'] / inch:8.4f}   {s['reduction_max_pct']:7.1f}   "
        f"{s['rms_disp_2nd_m']:.4e}  {s['rms_disp_2nd_m'] / inch:8.4f}   "
        f"{s['reduction_rms_pct']:7.1f}",
        '',
        'Table 9 layout: RTHS vs whole-numerical reference'
        + (' (here the uncontrolled building: a remote specimen has no model here)'
           if s['specimen'] == 'remote' else ''),
        (f"  actuator time delay {s['delay_ms_after']:.3f} ms, relative RMS error "
         f"{s['rths_vs_reference_rel_rms_pct']:.2f} %\n  reference: {s.get('reference_model')}"
         if s['rths_vs_reference_rel_rms_pct'] is not None else
         f"  none: the specimen is an {EXTERNAL} (the review has no model of it); actuator "
         f"time delay {s['delay_ms_after']:.3f} ms"),
        '',
        f"deadline misses: {s['deadline_misses']} ({s['deadline_miss_pct']:.3f} %)",
    ]
    if s.get('controller'):
        lines.append(controller_text(s['controller']))
    lines += notes(s)
    if s.get('every_dof'):
        lines += ['', 'Every DOF (relative displacement, RTHS; response.csv, /rths/response)',
                  '  DOF                  column       max [m]      RMS [m]']
        lines += [f"  {r['dof'][:20]:<20} {r['column']:<10} {r['max_m']:.4e}  {r['rms_m']:.4e}"
                  for r in s['every_dof']]
    return '\n'.join(lines) + '\n'


def print_review(summary: dict):
    """Print the review text."""
    print(review_text(summary), end='')


def residual_drift(disp, fs, seconds=1.0):
    """Mean 2nd-floor displacement [m] over the last ``seconds`` of the run."""
    disp = np.asarray(disp, dtype=float)
    return float(np.mean(disp[-max(1, int(seconds * fs)):])) if disp.size else float('nan')


def offline_references(numerical, bridge, dt, build=None):
    """Uncontrolled and reference responses from the run's own substructure, offline.

    The reference couples the same substructure with the run's specimen model on
    a perfect actuator (:meth:`rths_numerical.specimens.Specimen.reference`); the
    uncontrolled run has no specimen force.  Returns ``(uncontrolled, reference)``
    dicts with ``disp`` and ``metrics`` (the reference also its whole ``history``; None if the
    bridge ran a bare table).
    """
    build = build or (lambda: make_substructure(numerical))
    free = coupled_rths(build(), lambda x: np.zeros(1))
    uncontrolled = {'disp': free['output_disp'], 'metrics': metrics(free['output_disp'])}
    specimen = SPECIMENS.entry(specimen_of(bridge)).reference(dt, bridge)
    if specimen is None:
        return uncontrolled, None
    hist = coupled_rths(build(), specimen)
    return uncontrolled, {'disp': hist['output_disp'], 'history': hist,
                          'metrics': metrics(hist['output_disp'], uncontrolled['metrics'])}


def _hinge_history(bag, reference):
    """Hinge moment-rotation of the RTHS (the node's saved history), else of the reference."""
    path = Path(bag).parent / 'numerical_history.npz'
    if path.is_file():
        with np.load(path) as hist:
            if 'hinge_moment' in hist:
                return {'hinge_moment': hist['hinge_moment'],
                        'hinge_rotation': hist['hinge_rotation'], 'source': 'RTHS'}
    if reference and 'hinge_moment' in reference.get('history', {}):
        return dict(reference['history'], source='reference')
    return None
