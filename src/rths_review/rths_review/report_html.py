"""The one-file review: ``report.html`` with tables 5-9 and every plot embedded.

The page is self-contained: plots are inline base64 PNG (``data:`` URIs), the
style is inline, and nothing is fetched from the network, so it opens offline
in any browser and can be mailed as one file.
"""

import base64
import html
from pathlib import Path

from rths_common.rig import DOF_UNITS
from rths_review.realtime import realtime_text

#: The review's plots, in page order, with their captions.
PLOTS = {
    'time_history.png': '2nd-floor displacement: RTHS, whole-numerical reference and '
                        'uncontrolled building (tables 6-9)',
    'tracking_zoom.png': 'Actuator tracking around the peak: interface displacement, '
                         'compensated command and measured displacement (table 5)',
    'bode_actuator.png': 'Measured FRF of the actuator during the RTHS (table 5)',
    'specimen_hysteresis.png': 'Hysteretic specimen (e.g. the MR damper): measured force '
                               'against displacement',
}

_STYLE = ('body{font-family:sans-serif;max-width:60em;margin:1em auto;color:#222}'
          'table{border-collapse:collapse;margin:.5em 0 1.5em}'
          'th,td{border:1px solid #bbb;padding:.25em .6em;text-align:right}'
          'th:first-child,td:first-child{text-align:left}'
          'figure{margin:1em 0}img{max-width:100%}figcaption{font-size:.9em;color:#555}')
_INCH = 0.0254


def specimen_title(s: dict) -> str:
    """Return the specimen as a review's title names it (``valve4``, ``external ... H:P``)."""
    return s.get('specimen_label') or s['specimen']


def row_label(s: dict) -> str:
    """Return the specimen as a table row names it: its name, or ``external``."""
    return 'external' if s.get('specimen') == 'external controller' else s['specimen']


def _table(caption: str, header, rows) -> str:
    cells = ''.join(f'<th>{html.escape(str(h))}</th>' for h in header)
    body = ''.join('<tr>' + ''.join(f'<td>{html.escape(str(c))}</td>' for c in row) + '</tr>'
                   for row in rows)
    return (f'<h2>{html.escape(caption)}</h2>\n<table><tr>{cells}</tr>{body}</table>\n')


def tables(s: dict) -> str:
    """Return tables 5-9 of a review summary (:func:`rths_review.review.review_rths`) as HTML.

    A site review (``kind`` site) has table 5 only: its model ran in the client; a review
    of several actuators (``kind`` actuators) table 5 per actuator and interface DOF.
    """
    if s.get('kind') == 'actuators':
        return actuator_tables(s)
    out = _table('Table 5 layout: actuator time delay and relative RMS tracking error',
                 ('', 'before compensation', 'after compensation'),
                 (('time delay [ms]', f"{s['delay_ms_before']:.3f}", f"{s['delay_ms_after']:.3f}"),
                  ('rel. RMS error [%]', f"{s['tracking_rel_rms_pct_before']:.2f}",
                   f"{s['tracking_rel_rms_pct_after']:.2f}")))
    out += ('<p>before: plant input &rarr; output; after: interface displacement &rarr; '
            'output</p>\n')
    if s.get('kind') == 'site':
        return out + ('<p>Tables 6-9 need the numerical model, which ran in the client '
                      '(OpenSees/OpenFresco): not part of a site review.</p>\n')
    out += _table(
        f"Tables 6-8 layout: displacement of {s.get('dof', 'the output DOF')} (relative)",
        ('model', 'max [m]', 'max [in]', 'red. [%]', 'RMS [m]', 'RMS [in]', 'red. [%]'),
        (('uncontrolled', f"{s['uncontrolled_max_disp_2nd_m']:.4e}",
          f"{s['uncontrolled_max_disp_2nd_m'] / _INCH:.4f}", '-',
          f"{s['uncontrolled_rms_disp_2nd_m']:.4e}",
          f"{s['uncontrolled_rms_disp_2nd_m'] / _INCH:.4f}", '-'),
         (f"RTHS ({row_label(s)})", f"{s['max_disp_2nd_m']:.4e}",
          f"{s['max_disp_2nd_m'] / _INCH:.4f}", f"{s['reduction_max_pct']:.1f}",
          f"{s['rms_disp_2nd_m']:.4e}", f"{s['rms_disp_2nd_m'] / _INCH:.4f}",
          f"{s['reduction_rms_pct']:.1f}")))
    error = s['rths_vs_reference_rel_rms_pct']
    out += _table('Table 9 layout: RTHS vs whole-numerical reference',
                  ('actuator time delay [ms]', 'relative RMS error [%]'),
                  ((f"{s['delay_ms_after']:.3f}",
                    f'{error:.2f}' if error is not None else
                    'none: no model of the external controller\'s specimen'),))
    if s.get('reference_model'):
        out += f"<p>reference: {html.escape(s['reference_model'])}</p>\n"
    c = s.get('controller')
    if c:
        out += _table(f"Servo controller {c['address']} (protocol version "
                      f"{c['protocol_version']})",
                      ('replies used', 'lost', 'late', 'malformed', 'restarts',
                       'worst reply [ms]'),
                      ((c['replies'], c['replies_lost'], c['replies_late'],
                        c['replies_malformed'], c['restarts'], f"{c['worst_reply_ms']:.3f}"),))
        if c.get('fault'):
            out += f"<p>controller fault: {html.escape(c['fault'])}</p>\n"
    if s.get('every_dof'):
        out += _table('Every DOF: relative displacement in the RTHS (response.csv)',
                      ('DOF', 'column', 'max [m]', 'RMS [m]'),
                      [(r['dof'], r['column'], f"{r['max_m']:.4e}", f"{r['rms_m']:.4e}")
                       for r in s['every_dof']])
    return out


def _table5_row(name, r, extreme) -> tuple:
    return (name, f"{r['delay_ms_before']:.3f}", f"{r['delay_ms_after']:.3f}",
            f"{r['tracking_rel_rms_pct_before']:.2f}", f"{r['tracking_rel_rms_pct_after']:.2f}",
            extreme)


_TABLE5_HEADER = ('', 'delay before [ms]', 'delay after [ms]', 'rel. RMS error before [%]',
                  'rel. RMS error after [%]', 'largest target')


def actuator_tables(s: dict) -> str:
    """Return table 5 per actuator and per interface DOF of a several-actuator review."""
    out = _table('Table 5 layout per actuator: time delay and relative RMS tracking error',
                 _TABLE5_HEADER,
                 [_table5_row(f"{a['channel'] + 1}: {a['name']}", a,
                              f"{1e3 * a['max_abs_target_m']:.3f} mm") for a in s['actuators']])
    out += ('<p>before: command &rarr; measured stroke; after: target stroke &rarr; measured '
            'stroke</p>\n')
    if s.get('interface'):
        shown = {dof: unit_scale[1:] for dof, unit_scale in DOF_UNITS.items()}   # (unit, scale)
        out += _table('Table 5 layout per interface DOF (through the coupler)', _TABLE5_HEADER,
                      [_table5_row(r['dof'], r, f"{shown[r['dof']][1] * r['max_abs_target']:.3f} "
                                                f"{shown[r['dof']][0]}")
                       for r in s['interface']])
        m = s['interface_max']
        out += (f"<p>at the node: largest force {m['force_n']:.6g} N, moment "
                f"{m['moment_n_m']:.6g} N m; coupler from {html.escape(s['rig_source'])}</p>\n")
    else:
        out += f"<p>No interface DOFs: {html.escape(s['rig_source'])}</p>\n"
    return out + f"<p>{html.escape(s['tables_6_9'])}</p>\n"


def settings(s: dict) -> str:
    """Return what shaped the run (scale, force scale, frame, specimen, processing) as HTML."""
    if s.get('kind') == 'site':      # the record and the model ran in the client
        return ''
    if s.get('kind') == 'actuators':
        return _table('What shaped the run', ('', ''), (
            ('record', f"{s.get('record', '?')} x {s.get('scale', '?')}"),
            ('model', s.get('numerical_model', '?')),
            ('actuators', ', '.join(a['name'] for a in s['actuators'])
             + (f" ({s['rig']})" if s.get('rig') else '')),
            ('bridge backend', s.get('backend', '?'))))
    rows = [('record', f"{s.get('record', '?')} x {s.get('scale', '?')}"),
            ('specimen', s.get('specimen', '?')),
            ('model', f"{s.get('numerical_model', '?')}"),
            ('force scale', f"{s.get('force_scale', '?')}"),
            ('interface frame', f"{s.get('interface_frame', '?')} at "
                                f"{', '.join(s.get('interface_dofs', []))}"),
            ('input processing', '; '.join(s.get('input_processing') or []) or 'none')]
    return _table('What shaped the run', ('', ''), rows)


def realtime_table(s: dict) -> str:
    """Return the real-time figures of a realtime run against its limits ("" in lock-step)."""
    if 'realtime_ok' not in s:
        return ''
    lim = s['realtime_limits']
    rows = (('late or missed ticks [%]', f"{s['late_or_missed_pct']:.3f}",
             f"{lim['late_or_missed_pct']:g}"),
            ('clock overruns', f"{s['clock_overruns']} ({s['stalled_ticks']} ticks skipped)",
             '-'),
            ('worst period [ms]', f"{s['worst_period_ms']:.3f}", f"{lim['worst_period_ms']:g}"),
            ('behind real time [s]', f"{s['behind_s']:.3f}", f"{lim['behind_s']:g}"),
            ('verdict', 'real time' if s['realtime_ok'] else 'NOT REAL TIME', ''))
    return _table('Real time', ('', 'this run', 'limit'), rows)


def notes(s: dict) -> list:
    """Return the lines after the tables: real time, a cut-short run, faults, repairs."""
    lines = []
    if 'realtime_ok' in s:
        lines.append(realtime_text(s))
    if s.get('cut_short'):
        fs = s['fs_hz']
        lines.append(f"CUT SHORT: the run stopped after {s['recorded_steps']} of its "
                     f"{s['planned_steps']} steps ({s['recorded_steps'] / fs:.2f} of "
                     f"{s['planned_steps'] / fs:.2f} s); the review covers "
                     f"{s['steps']} steps")
    if s.get('safety_faults'):
        lines.append('safety faults: ' + '; '.join(s['safety_faults']))
    for topic, rec in s.get('recording', {}).items():
        lines.append(f"recording of {topic}: {rec['resent']} re-sent step(s) dropped, "
                     f"{rec['filled']} step(s) missing from the bag filled linearly")
    if s.get('recording_complete') is False:
        fs = s['fs_hz']
        gaps = s.get('recording_gaps', [])
        where = ', '.join(f"{g['topic'].rsplit('/', 1)[-1]} {g['steps']} step(s) from step "
                          f"{g['first_step']} ({g['start_s']:.3f} s)" for g in gaps[:5])
        more = f' and {len(gaps) - 5} more gap(s)' if len(gaps) > 5 else ''
        lines.append(f"RECORDING INCOMPLETE: the bag lacks steps (longest gap "
                     f"{s['recording_longest_gap_steps']} steps, "
                     f"{s['recording_longest_gap_steps'] / fs:.3f} s): {where}{more}; the "
                     f"tracking errors are computed on the {s['recording_kept_pct']:.2f} % of "
                     'the steps the bag holds, the delays and responses with the gaps filled '
                     'linearly')
    return lines


def _figure(name: str, data: bytes, caption: str) -> str:
    uri = 'data:image/png;base64,' + base64.b64encode(data).decode('ascii')
    return (f'<figure><img alt="{html.escape(name)}" src="{uri}">'
            f'<figcaption>{html.escape(caption)} ({html.escape(name)})</figcaption></figure>\n')


def render(summary: dict, images: dict) -> str:
    """Return the whole page; ``images`` maps a plot's file name to its PNG bytes."""
    s = summary
    what = (f"site review: backend {s['backend']}"
            if s.get('kind') == 'site' else f"RTHS review: {s['record']} x {s['scale']}")
    who = (f"{s['n_actuators']} actuators" if s.get('kind') == 'actuators'
           else f'specimen {specimen_title(s)}')
    title = (f"{what}, {who}, {s['mode']}, "
             f"{s['steps']} steps at {s['fs_hz']:g} Hz ({s['duration_s']:.1f} s)")
    misses = f"deadline misses: {s['deadline_misses']} ({s['deadline_miss_pct']:.3f} %)"
    extra = ''.join(f'<p>{html.escape(line)}</p>\n' for line in notes(s)
                    if not line.startswith('safety faults'))
    faults = ''.join(f'<li>{html.escape(f)}</li>' for f in s.get('safety_faults', []))
    captions = dict(PLOTS, **{name: text for name, text in s.get('plots', [])})
    figures = ''.join(_figure(name, data, captions.get(name, name))
                      for name, data in images.items())
    comp = s.get('compensator') or {}
    scheme = ', '.join(f'{k} {v}' for k, v in comp.items() if k != 'plant')
    return (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f'<title>{html.escape(title)}</title><style>{_STYLE}</style></head>\n<body>\n'
            f'<h1>{html.escape(title)}</h1>\n<p>compensator: {html.escape(scheme) or "-"}</p>\n'
            + settings(s) + tables(s) + realtime_table(s)
            + f'<p>{html.escape(misses)}</p>\n' + extra
            + (f'<p>safety faults:</p><ul>{faults}</ul>\n' if faults else '')
            + figures + '</body></html>\n')


def render_stop(summary: dict, text: str) -> str:
    """Return the page of a run the bridge's safety supervisor stopped too early for tables 5-9.

    ``text``: the printed report of the stop (``rths_bringup.run.safety_stop_text``).
    """
    title = (f"RTHS ABORTED by the bridge's safety supervisor: {summary.get('record')} x "
             f"{summary.get('scale')}, {summary.get('mode')}")
    return (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f'<title>{html.escape(title)}</title><style>{_STYLE}</style></head>\n<body>\n'
            f'<h1>{html.escape(title)}</h1>\n'
            f'<p>No tables 5-9: the run stopped before 2 s of it could be reviewed.</p>\n'
            f'<pre>{html.escape(text)}</pre>\n' + realtime_table(summary)
            + '</body></html>\n')


def write_stop_report(out_dir, summary: dict, text: str) -> Path:
    """Write ``out_dir/report.html`` of a run stopped too early for a review (render_stop)."""
    path = Path(out_dir) / 'report.html'
    tmp = path.with_suffix('.html.tmp')
    tmp.write_text(render_stop(summary, text), encoding='utf-8')
    tmp.replace(path)
    return path


def write_report(out_dir, summary: dict) -> Path:
    """Write ``out_dir/report.html`` from ``summary`` and the PNG plots in ``out_dir``."""
    out_dir = Path(out_dir)
    names = [name for name, _ in summary['plots']] if 'plots' in summary else list(PLOTS)
    images = {name: (out_dir / name).read_bytes() for name in names if (out_dir / name).is_file()}
    path = out_dir / 'report.html'
    tmp = path.with_suffix('.html.tmp')
    tmp.write_text(render(summary, images), encoding='utf-8')
    tmp.replace(path)
    return path
