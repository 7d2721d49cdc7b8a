"""Review of a run with several actuators on one specimen (a rig file, docs/multi_actuator.md).

The bag holds one entry per actuator in every loop message: the numerical node's target
strokes (``/rths/interface_displacement``), the commands the bridge wrote, the measured
strokes and the load cells' axial forces (``/rths/measurement``).  The review gives each
actuator the single-actuator review's Table 5 (delay and relative RMS tracking error,
before compensation: command -> measured; after: target -> measured) and its tracking
and FRF plots, and the interface DOFs ``x`` [m] and ``theta`` [rad] the same table, their
targets, commands and measurements taken through the coupler (:mod:`rths_common.rig`),
with the force and moment the load cells put on the node.

The coupler is the rig file's (its actuator names and kinematics) when the file the run
named is still there, else the numerical substructure's own (the run's model, exact
kinematics).  Tables 6-9 compare the building with its whole-numerical reference, which
this review does not rebuild for a several-actuator model: ``rths bench marths --via
graph`` computes the benchmark's J1-J10 against its reference structure.
"""

import json
import os
from pathlib import Path

import numpy as np

from rths_common import runinfo
from rths_common.rig import DOF_UNITS, load_rig
from rths_common.rig import DOFS as RIG_DOFS
from rths_review import plots
from rths_review.report_html import notes, write_report
from rths_review.tracking import (
    REVIEW_STAGES,
    bridge_realtime,
    run_account,
    table5_of,
    tracking_channels,
)

#: Interface DOFs of a coupler, with their unit (SI) and the unit they are printed in.
DOFS = tuple((dof, *DOF_UNITS[dof]) for dof in RIG_DOFS)
#: What the several-actuator review leaves out, and where it is.
NO_TABLES_6_9 = ('Tables 6-9 (the building against its whole-numerical reference) are not part '
                 'of a several-actuator review: rths bench marths --via graph computes the '
                 "benchmark's J1-J10 against its reference structure")


def rig_of(bridge: dict, sub, where: str) -> dict:
    """Return ``{'names', 'coupler', 'linear', 'source'}`` of a run's actuators.

    The rig file the bridge named, when it still reads; else the numerical substructure's
    coupler (``sub.coupler``), exact kinematics, actuators named by channel; else no
    coupler (``coupler`` None: no interface DOFs).
    """
    n = int(sub.n_interface)
    path = str(bridge.get('rig_file') or '')
    note = ''
    if path and os.path.isfile(path):
        try:
            rig = load_rig(path)
        except ValueError as err:
            note = f'{err}'
        else:
            if rig.n == n:
                return {'names': list(rig.actuators), 'coupler': rig.coupler,
                        'linear': rig.linear, 'source': f'rig file {path}',
                        'rig_name': rig.name}
            note = f'rig file {path} lists {rig.n} actuators, the run had {n}'
    elif path:
        note = f'rig file {path} is not there any more'
    coupler = getattr(sub, 'coupler', None)
    names = [f'actuator {i + 1}' for i in range(n)]
    if coupler is not None and coupler.n == n:
        source = 'the numerical model\'s coupler (exact kinematics)'
        return {'names': names, 'coupler': coupler, 'linear': False,
                'source': source + (f'; {note}' if note else ''), 'rig_name': ''}
    return {'names': names, 'coupler': None, 'linear': False, 'rig_name': '',
            'source': 'no coupler: ' + (note or 'the run named no rig file')}


def _dofs(coupler, strokes, linear):
    x, theta = coupler.dofs(np.asarray(strokes, float).T, linear=linear)
    return np.column_stack([np.ravel(x), np.ravel(theta)])


def review_actuators(bag, out_dir, info: dict, fs: float, sub, stage, limits=None) -> dict:
    """Review a bag of several actuators: Table 5 per actuator and per interface DOF.

    Writes ``summary.json`` (``kind: actuators``; ``actuators``: one Table 5 per actuator
    with its name and extremes; ``interface``: the same for ``x`` and ``theta``;
    ``interface_max``: the node's largest force and moment), ``review.txt``, the plots
    (per actuator ``tracking_zoom_<i>.png``, ``bode_actuator_<i>.png``; ``interface_dofs.png``)
    and ``report.html``.  ``stage(done, 4)`` as :func:`rths_review.review.review_rths`.
    """
    bag, out_dir = Path(bag), Path(out_dir)
    n_act = int(sub.n_interface)
    desired, applied, measured, meas, status, n, recorded, recording, kept = tracking_channels(
        bag, fs, channels=n_act)
    if desired.shape[1] != n_act or measured.shape[1] != n_act:
        raise ValueError(f'{bag}: the bag holds {min(desired.shape[1], measured.shape[1])} '
                         f'actuator channel(s) but its numerical model drives {n_act}; was '
                         'the bridge given the rig file?')
    force = meas['force'][:n, :n_act]
    timing = bridge_realtime(status, sub.n_steps, fs, limits) if (
        info.get('mode') == 'realtime') else None
    stage(1, REVIEW_STAGES)
    bridge = runinfo.section(info, 'bridge')
    numerical = runinfo.section(info, 'numerical')
    rig = rig_of(bridge, sub, f'{bag}: bridge parameter rig_file')
    actuators = []
    for i, name in enumerate(rig['names']):
        actuators.append({
            'channel': i, 'name': name,
            **table5_of(desired[:, i], applied[:, i], measured[:, i], fs, kept),
            'max_abs_target_m': float(np.max(np.abs(desired[:, i]))),
            'max_abs_command_m': float(np.max(np.abs(applied[:, i]))),
            'max_abs_measured_m': float(np.max(np.abs(measured[:, i]))),
            'max_abs_force_n': float(np.max(np.abs(force[:, i]))),
        })
    interface, interface_max, pose = [], None, None
    if rig['coupler'] is not None:
        pose = {k: _dofs(rig['coupler'], v, rig['linear'])
                for k, v in (('desired', desired), ('applied', applied), ('measured', measured))}
        for j, (dof, unit, _, _) in enumerate(DOFS):
            interface.append({
                'dof': dof, 'unit': unit,
                **table5_of(pose['desired'][:, j], pose['applied'][:, j],
                            pose['measured'][:, j], fs, kept),
                'max_abs_target': float(np.max(np.abs(pose['desired'][:, j]))),
                'max_abs_measured': float(np.max(np.abs(pose['measured'][:, j])))})
        f_node, m_node = rig['coupler'].interface_forces(
            force.T, 0.0 if rig['linear'] else pose['measured'][:, 1])
        pose['forces'] = np.column_stack([np.ravel(f_node), np.ravel(m_node)])
        interface_max = {'force_n': float(np.max(np.abs(pose['forces'][:, 0]))),
                         'moment_n_m': float(np.max(np.abs(pose['forces'][:, 1])))}
    stage(2, REVIEW_STAGES)
    summary = {
        'kind': 'actuators', 'record': numerical.get('record'), 'scale': numerical.get('scale'),
        'mode': info.get('mode'), 'fs_hz': fs, 'steps': n, 'duration_s': n / fs,
        'compensator': runinfo.section(info, 'compensator'),
        'numerical_model': str(numerical.get('model')),
        'backend': bridge.get('backend'),
        'n_actuators': n_act, 'rig': rig['rig_name'], 'rig_source': rig['source'],
        'actuators': actuators, 'interface': interface, 'interface_max': interface_max,
        'tables_6_9': NO_TABLES_6_9,
        **run_account(bag, status, sub.n_steps, recorded, recording, kept, timing),
    }
    figures = []
    for i, name in enumerate(rig['names']):
        label = f'actuator {i + 1}' + (f' ({name})' if name != f'actuator {i + 1}' else '')
        plots.tracking_plots(out_dir, fs, desired[:, i], applied[:, i], measured[:, i],
                             suffix=f'_{i + 1}', title=label)
        figures += [(f'tracking_zoom_{i + 1}.png', f'{label}: tracking around the peak: '
                     'target stroke, compensated command and measured stroke (table 5)'),
                    (f'bode_actuator_{i + 1}.png', f'{label}: measured FRF during the RTHS '
                     '(table 5)')]
    if pose is not None:
        plots.interface_plot(out_dir / 'interface_dofs.png', fs, pose['desired'],
                             pose['measured'], pose['forces'],
                             title=f'interface DOFs through the coupler ({rig["source"]})')
        figures.append(('interface_dofs.png', 'Interface DOFs x and theta: target and '
                        'measured, through the coupler; force and moment of the load cells at '
                        'the node'))
    summary['plots'] = [list(f) for f in figures]
    (out_dir / 'summary.json').write_text(json.dumps(summary, indent=2))
    (out_dir / 'review.txt').write_text(actuators_text(summary))
    stage(3, REVIEW_STAGES)
    write_report(out_dir, summary)
    stage(4, REVIEW_STAGES)
    return summary


def _table5_rows(rows) -> list:
    lines = ['  ' + 'name'.ljust(18) + 'delay before [ms]  after [ms]   '
             'rel. RMS before [%]  after [%]   max target']
    for r in rows:
        lines.append(f"  {r['_name'][:17]:<18}{r['delay_ms_before']:>17.3f}"
                     f"{r['delay_ms_after']:>12.3f}{r['tracking_rel_rms_pct_before']:>22.2f}"
                     f"{r['tracking_rel_rms_pct_after']:>11.2f}   {r['_max']}")
    return lines


def actuators_text(s: dict) -> str:
    """Return the review text of a several-actuator run (``kind: actuators``)."""
    lines = [f"RTHS review: {s['record']} x {s['scale']}, {s['n_actuators']} actuators"
             + (f" ({s['rig']})" if s.get('rig') else '') + f", {s['mode']}, {s['steps']} "
             f"steps at {s['fs_hz']:g} Hz ({s['duration_s']:.1f} s)",
             f"  model {s['numerical_model']}, backend {s.get('backend')}; coupler from "
             f"{s['rig_source']}", '',
             'Table 5 layout per actuator (before: command -> measured stroke; after: target '
             '-> measured stroke)']
    lines += _table5_rows([dict(a, _name=f"{a['channel'] + 1} {a['name']}",
                                _max=f"{1e3 * a['max_abs_target_m']:.3f} mm")
                           for a in s['actuators']])
    if s['interface']:
        lines += ['', 'Table 5 layout per interface DOF, through the coupler']
        lines += _table5_rows([dict(r, _name=r['dof'],
                                    _max=f"{1e3 * r['max_abs_target']:.3f} "
                                         f"{dict((d, u) for d, _, u, _ in DOFS)[r['dof']]}")
                               for r in s['interface']])
        m = s['interface_max']
        lines.append(f"  at the node: largest force {m['force_n']:.6g} N, moment "
                     f"{m['moment_n_m']:.6g} N m")
    else:
        lines += ['', f"No interface DOFs: {s['rig_source']}"]
    lines += ['', s['tables_6_9'], '',
              f"deadline misses: {s['deadline_misses']} ({s['deadline_miss_pct']:.3f} %)"]
    lines += notes(s)
    return '\n'.join(lines) + '\n'
