"""``rths run``: the whole lab procedure of seed chapter 6 in one command.

1. identification run: the bridge drives the plant (actuator + table + DTM)
   with BLWN (the numerical node plays ``model: excitation``, identity taps),
   recorded to ``OUT/identification/bag``;
2. ARX identification and FIR design (``rths identify`` and ``rths design``:
   WLS, fc = 10 Hz, n = 400 as in seed section 6.1 unless overridden), written to
   ``OUT/plant.yaml`` and ``OUT/compensator.yaml`` (never into ``CONFIG``: installing
   them as the lab's taps is ``rths install-taps OUT``);
3. the RTHS run: the building (numerical node), the compensator and the bridge
   with the simulated DTM, recorded to ``OUT/rths/bag``;
4. the review (:mod:`rths_review.review`): tables 5-9 as text, ``OUT/summary.json``
   and PNG plots.

Every phase writes the exact params files it ran with under ``OUT/<phase>/config``.

Safety stop.  If the bridge's safety supervisor stops the RTHS (e.g. an uncompensated
loop that goes unstable trips the instability detector), the bridge exits with code 3
and the launcher with 1 (``node bridge died (exit code 3: safety stop)``).  ``rths run``
then reads the bag (:func:`read_safety_stop`), writes ``OUT/summary.json`` and
``OUT/review.txt`` with ``safety_stop`` (the bridge's fault text), the fault and stop
steps, the ``steps`` run and the final actuator position (:func:`safety_stop_summary`),
prints them and exits with :data:`EXIT_SAFETY_STOP`.  The run is still reviewed up to
the fault (after it the plant holds and ramps to the safe position, which no reference
describes): with at least 2 s before the fault, tables 5-9 of those steps, the plots and
``OUT/report.html``, the stop's figures beside them (``reviewed_steps`` the steps the
tables cover); with less, ``OUT/report.html`` holds the stop's report and real-time
figures only.
"""

import datetime
import json
from pathlib import Path
import sys

from rths_bringup import isolation
from rths_bringup.commands import default_config_dir, launch
from rths_common import runinfo
from rths_common.params import add_renamed_option, renamed
from rths_compensator.methods import DEFAULT as METHOD_DEFAULT
from rths_compensator.methods import METHODS, adaptive_names
from rths_compensator.params import PROVENANCE, identity_params
from rths_compensator.schemes import DEFAULT_SCHEME, DESIGN_DEFAULTS, designed
from rths_numerical.ground_motion import FORMATS, SEED_SCALES
from rths_numerical.specimens import (
    DEFAULT_SPECIMEN,
    SPECIMENS,
    specimen_of,
    specimen_settings,
)

# Imports of the commands' code sit in the command functions: rths imports this module
# to build its parser, and every rths command would pay for SciPy, matplotlib and ROS.

NODE_FILES = {'numerical': 'numerical.yaml', 'compensator': 'compensator.yaml',
              'bridge': 'bridge.yaml'}
#: Exit code of ``rths run`` when the bridge's safety supervisor stopped the RTHS run
#: (the bridge node's own exit code for a safety stop, launcher.EXIT_MEANINGS).
EXIT_SAFETY_STOP = 3
#: Safety state numbers of rths_msgs/LoopStatus (rths_actuator_bridge.safety).
ACTIVE, STOPPED = 0, 3


def register(commands, benches):
    """Add ``rths run`` and ``rths review``."""
    p = commands.add_parser(
        'run', help='the main job: identify, design, run the RTHS, review (seed chapter 6)',
        description='Perform the whole lab procedure of seed chapter 6: (1) identification run '
        'with BLWN, (2) ARX identification and FIR design written to OUT/compensator.yaml '
        '(config/ is never written; rths install-taps OUT installs them), (3) the RTHS of '
        'the 2-story building with the simulated DTM, (4) the review: actuator delay '
        'and tracking error before/after compensation (table 5), 2nd-floor response and '
        'reductions vs the uncontrolled building (tables 6-8), RTHS vs whole-numerical '
        'reference (table 9), written to OUT/report.html (one file, plots embedded), '
        'OUT/summary.json, OUT/review.txt and PNG plots.')
    p.add_argument('--config', default=None, help='config directory (default: repo config/)')
    p.add_argument('--out', default=None, help='results directory (default: out/run-<time>)')
    p.add_argument('--record', default='kobe',
                   help='ground motion: kobe, northridge, imperial_valley (the seed\'s records) '
                        'or a record file: PEER .AT2; CSV or whitespace text (.csv .txt .dat '
                        '.tsv .asc) with a time and an acceleration column; one column of '
                        'accelerations with --record-dt (default kobe)')
    p.add_argument('--record-format', default='', choices=('',) + FORMATS.names(),
                   help='the record file\'s format (default: by its ending and its content)')
    p.add_argument('--record-units', default='',
                   help='acceleration unit of a record whose header does not name it: g, '
                        'm/s^2, cm/s^2 or gal (refused if it contradicts the header)')
    p.add_argument('--record-dt', type=float, default=0.0,
                   help='time step [s] of a single-column record')
    p.add_argument('--no-resample', action='store_true',
                   help='do not resample the record to the loop rate (its rate must be fs_hz)')
    p.add_argument('--no-mean-removal', action='store_true',
                   help="keep the record's mean acceleration")
    p.add_argument('--no-baseline', action='store_true',
                   help='no baseline correction (a cubic polynomial fitted to the ground '
                        'displacement is removed by default)')
    p.add_argument('--scale', type=float, default=None,
                   help='ground-motion scale factor (default: 1 for a record file; the seed\'s '
                        'factor for its records: kobe 0.135, northridge 0.039, '
                        'imperial_valley 0.10)')
    p.add_argument('--specimen', default=None, type=_specimen_arg,
                   choices=_RemoteOr(SPECIMENS.names()),
                   help=f'the specimen (default: the specimen of CONFIG/bridge.yaml, else '
                        f'{DEFAULT_SPECIMEN}; given, it overrides the config with a note): '
                        'an entry of '
                        'rths_numerical.specimens (docs/extending.md lists them: the Table 4 '
                        'DTMs, the bare table, a damper between the floor and the ground), or '
                        'tcp://HOST:PORT: a remote experimental site (rths site, OpenFresco; '
                        'the bridge speaks the OpenSees genericClient protocol to it; steps 1-2 '
                        'are skipped: the site compensates its own actuator, identity taps here; '
                        'the review compares with the uncontrolled building)')
    add_renamed_option(p, '--damper', '--specimen')
    p.add_argument('--mr-voltage', type=float, default=None,
                   help='the MR damper: constant command voltage [V] (Spencer et al. 1997 '
                        'tested 0-2.25 V; default 1.0); --specimen-param mr_voltage_v=V')
    p.add_argument('--specimen-param', action='append', default=[], metavar='KEY=VALUE',
                   help="a parameter of the specimen's own (bridge.yaml keys such as "
                        'mr_voltage_v; repeatable)')
    p.add_argument('--backend', choices=('simulated', 'udp'), default='simulated',
                   help='simulated (default): the plant model in the bridge; udp: a servo '
                        "controller (--controller), the lab's own actuator and specimen "
                        '(docs/controller_protocol.md)')
    p.add_argument('--controller', default=None, metavar='HOST:PORT',
                   help='--backend udp: the servo controller (e.g. 192.168.1.20:5005; '
                        'rths controller-emulator prints its own)')
    p.add_argument('--force-scale', type=float, default=None,
                   help='specimens the one in the lab stands for: its measured force is '
                        'multiplied by this in the model (default: 5 for building2story, seed '
                        '6.2; 1 for any other model)')
    p.add_argument('--numerical', choices=('builtin', 'opensees'), default='builtin',
                   help='numerical backend: builtin (default) or opensees (OpenSeesPy, `make '
                        'setup-opensees`; integrator central_difference)')
    p.add_argument('--model', default='building2story',
                   help='numerical model: building2story (default), a model YAML, or with '
                        '--numerical opensees an OpenSeesPy script (.py, or a name in '
                        'config/models/, e.g. frame-steel01)')
    p.add_argument('--output-dof', default=None,
                   help="the DOF the review's tables report: a name of the model's DOFs or a "
                        "number from 1 (default: the model's output_dof); checked before the run")
    p.add_argument('--mode', choices=('lockstep', 'realtime'), default='lockstep',
                   help='timing mode (default lockstep: deterministic, as fast as possible)')
    p.add_argument('--layout', choices=('composed', 'processes'), default=None,
                   help='composed: the three nodes in one process on one executor; processes: '
                        'one process per node (default: composed in realtime, processes in '
                        'lock-step)')
    p.add_argument('--duration', type=float, default=0.0,
                   help='simulated seconds of the RTHS run (default 0: the whole record)')
    p.add_argument('--scheme', default=DEFAULT_SCHEME, choices=designed(),
                   help=f'compensator scheme (default {DEFAULT_SCHEME}; rths design --help)')
    p.add_argument('--fc', type=float, default=None,
                   help=f'FIR cut-off [Hz] (default as rths design: {DESIGN_DEFAULTS["fc_hz"]:g}, '
                        'higher for a plant with a long dead time)')
    p.add_argument('--taps', type=int, default=DESIGN_DEFAULTS['n_taps'],
                   help=f'FIR taps n (default {DESIGN_DEFAULTS["n_taps"]}, as rths design)')
    p.add_argument('--ident-na-max', type=int, default=None,
                   help='identification: largest na (default: rths identify\'s)')
    p.add_argument('--ident-nb-max', type=int, default=None,
                   help='identification: largest nb (default: rths identify\'s)')
    p.add_argument('--ident-d-min', type=int, default=None,
                   help='identification: smallest dead time [samples] (default: estimated from '
                        'the run and searched around)')
    p.add_argument('--ident-d-max', type=int, default=None,
                   help='identification: largest dead time [samples] (default: estimated)')
    p.add_argument('--ident-method', default='oe', choices=('oe', 'arx-grid'),
                   help='identification method (default oe; rths identify --help)')
    p.add_argument('--accept-poor-fit', action='store_true',
                   help='run the RTHS even when the identified plant\'s validation fit is poor '
                        '(default: stop before it)')
    p.add_argument('--ident-duration', type=float, default=40.0,
                   help='identification run length [s] (default 40: 4 records of 10 s)')
    p.add_argument('--plant', default=None,
                   help='skip steps 1-2 and design from this identified plant.yaml (or an '
                        'updated_model.yaml of rths discrepancy --scenario actuator)')
    p.add_argument('--specimen-model', default=None, metavar='MODEL.yaml',
                   help="step 4's Table 9 against the reference with this specimen model "
                        '(the updated_model.yaml of rths discrepancy --scenario specimen) '
                        "instead of the specimen's nominal one; the review names it")
    p.add_argument('--adaptive', default=METHOD_DEFAULT, choices=METHODS.names(),
                   help=f'compensation method of the RTHS run (default {METHOD_DEFAULT}: the '
                        f'designed FIR; {", ".join(adaptive_names())} adapt on line from it; '
                        'pi_lead: the RTHS benchmark\'s PI + lead feedback controller, the '
                        'designed FIR its fallback; lock-step or realtime; docs/adaptive.md)')
    p.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap',
                   help='storage of the bags (default mcap; sqlite3 for older tools)')
    p.add_argument('--no-compensation', action='store_true',
                   help='skip steps 1-2 and run with identity taps (shows the uncompensated '
                        'error and, where the loop goes unstable, the safe abort)')
    add_limit_arguments(p)
    from rths_live import live
    live.add_arguments(p)
    p.epilog = ('Exit codes: 0 the run completed and was reviewed; 3 the bridge\'s safety '
                'supervisor stopped the RTHS (OUT/summary.json then holds safety_stop, the '
                'fault text, and the steps run; e.g. --no-compensation --specimen novalve '
                '--force-scale 60 goes unstable); 1 a phase failed; 2 bad input.')
    p.set_defaults(func=cmd_run)

    p = commands.add_parser(
        'review', help='rebuild the review (tables 5-9, plots, summary.json) from an RTHS bag',
        description='Rebuild the step-4 report of rths run from a recorded RTHS bag alone: '
                    'the run parameters are read from the bag run information, the reference '
                    'and uncontrolled simulations are recomputed.')
    p.add_argument('bag', help='bag directory of an RTHS run')
    p.add_argument('--out', default=None, help='directory for summary.json, review.txt and '
                   'plots (default: beside the bag)')
    p.add_argument('--dof', default=None,
                   help="the DOF tables 6-9 report: a name of the model's DOFs or a number from 1 "
                        "(default: the model's output DOF); every DOF is listed anyway")
    p.add_argument('--specimen-model', default=None, metavar='MODEL.yaml',
                   help='Table 9 against the reference with this specimen model (the '
                        'updated_model.yaml of rths discrepancy --scenario specimen) instead '
                        "of the run's nominal specimen; the review names the model it used")
    add_limit_arguments(p)
    p.set_defaults(func=cmd_review)


def add_limit_arguments(p):
    """Add the real-time limits a realtime run is judged by (realtime_ok in summary.json)."""
    from rths_review.realtime import REALTIME_LIMITS as lim

    g = p.add_argument_group('real-time limits (realtime mode: beyond any of them the summary '
                             'says realtime_ok false and the review NOT REAL TIME)')
    g.add_argument('--max-late-pct', type=float, default=lim['late_or_missed_pct'],
                   help='largest share of ticks late or missed: deadline misses plus ticks '
                        'skipped by clock stalls [%%] (default %(default)g)')
    g.add_argument('--max-period-ms', type=float, default=lim['worst_period_ms'],
                   help='longest time between two ticks of the bridge\'s clock [ms] '
                        '(default %(default)g)')
    g.add_argument('--max-behind-s', type=float, default=lim['behind_s'],
                   help='longest total time the run fell behind real time [s] '
                        '(default %(default)g)')


def limits_of(args) -> dict:
    """Return the real-time limits of ``rths run`` / ``rths review`` (checked)."""
    from rths_review.realtime import check_limits

    return check_limits({'late_or_missed_pct': args.max_late_pct,
                         'worst_period_ms': args.max_period_ms, 'behind_s': args.max_behind_s})


def _say(text):
    print(f'[run] {text}', flush=True)


def _phase_config(out_dir: Path, sections: dict) -> Path:
    """Write the three params files of one phase (``sections``: node -> params); return the dir."""
    cfg = out_dir / 'config'
    for node, fname in NODE_FILES.items():
        runinfo.write_params(cfg / fname, node, sections[node])
    return cfg


def _launch_phase(name, cfg, bag, kind, fs, mode, sections, history=None, storage=None,
                  live=False, layout=None):
    """Run one phase of the graph; return None, or the bridge's safety stop (a dict).

    A launcher failure that is not the bridge's safety stop raises RuntimeError.
    """
    overrides = {'recorder': runinfo.flatten(kind, fs, mode, sections)}
    if history:
        overrides['numerical'] = {'history_out': str(Path(history).resolve())}
    for node in NODE_FILES:
        overrides.setdefault(node, {})['mode'] = mode
    _say(f'{name}: launching the node graph ({mode}), recording to {bag}')
    code = launch(cfg, bag=bag, overrides=overrides, timeout=3600.0, storage=storage, live=live,
                  layout=layout, progress_label=f'{name} run')
    if code == 0:
        return None
    try:
        stop = read_safety_stop(bag) if Path(bag).exists() else None
    except Exception as err:  # an unreadable bag: report the launcher's failure instead
        _say(f'{name}: could not read the bag {bag} ({err})')
        stop = None
    if stop is None:
        raise RuntimeError(f'{name} run failed (launcher exit {code}); see the log above '
                           f'and the bag {bag}')
    stop['launcher_exit'] = code
    _say(f'{name}: launcher exit {code}: the bridge\'s safety supervisor stopped the run '
         f'(fault at step {stop["fault_step"]}: {stop["safety_stop"]})')
    return stop


def safety_stop_summary(step, state, fault, applied, displacement, force, fs_hz: float,
                        safe_position_m: float = 0.0) -> dict:
    """Summarise a run that the bridge's safety supervisor stopped (pure; SI units).

    ``step``, ``state`` (LoopStatus safety state), ``applied`` (command written
    [m]), ``displacement`` (measured [m]) and ``force`` (measured force [N]) are
    per-step arrays of channel 0 in step order; ``fault`` is the bridge's fault
    text.  ``steps`` is the number of loop steps run (through hold, ramp and stop),
    ``fault_step`` the first step not ACTIVE, ``stop_step`` the first STOPPED one;
    ``force_rms_per_s_n`` is the RMS force oscillation (force minus its mean) of
    each whole second before the fault, which shows the growth of an unstable loop.
    """
    import numpy as np

    step = np.asarray(step, dtype=np.int64)
    state = np.asarray(state, dtype=np.int64)
    force = np.asarray(force, dtype=float)
    fs = float(fs_hz)
    tripped = np.flatnonzero(state != ACTIVE)
    stopped = np.flatnonzero(state == STOPPED)
    if not tripped.size or not stopped.size:
        raise ValueError('the run has no safety stop (no STOPPED state)')
    i_fault, i_stop = int(tripped[0]), int(stopped[0])
    before = force[:i_fault]
    per_s = int(round(fs))
    rms = [float(np.sqrt(np.mean((w - w.mean()) ** 2)))
           for w in (before[i:i + per_s] for i in range(0, before.size - per_s + 1, per_s))]
    written = np.asarray(applied, dtype=float)[:i_stop + 1]
    written = written[np.isfinite(written)]
    return {
        'safety_stop': fault,
        'fault_step': int(step[i_fault]), 'fault_time_s': float(step[i_fault] / fs),
        'stop_step': int(step[i_stop]), 'stop_time_s': float(step[i_stop] / fs),
        'steps': int(step.size),
        'safe_position_m': float(safe_position_m),
        'final_command_m': float(written[-1]) if written.size else None,
        'final_displacement_m': float(np.asarray(displacement, dtype=float)[i_stop]),
        'max_abs_command_m': float(np.max(np.abs(written))) if written.size else None,
        'max_abs_force_before_fault_n': float(np.max(np.abs(before))) if before.size else 0.0,
        'force_rms_per_s_n': [round(v, 1) for v in rms],
    }


def read_safety_stop(bag):
    """Return the bridge's safety stop recorded in a bag (:func:`safety_stop_summary`), else None.

    None when the bridge never reported a fault, or reported one but neither
    its STOPPED status nor a last command at the safe position is in the bag.  A
    recorder that lagged the loop (processes layout, loaded machine) may close
    the bag before the last statuses of the stop reach it: when the bag's last
    status of the bridge is HOLD or RAMP and its last command written is the
    safe position, the bag's last measured step stands for the stop
    (``stop_step``, with ``stop_inferred``: True; the real STOPPED step is not
    known, and the report says so).  The summary also holds the run's parameters from
    the bag's run information and every distinct fault the bridge reported
    (``safety_faults``).
    """
    import numpy as np

    from rths_common import bagio, topics

    status = {}
    faults = []
    for _, _, msg in bagio.read_messages(bag, [topics.STATUS]):
        if msg.node == 'bridge':
            status[int(msg.step)] = int(msg.safety_state)
            if msg.fault and msg.fault not in faults:
                faults.append(msg.fault)
    if not faults:
        return None
    info = bagio.run_info(bag)
    bridge = runinfo.section(info, 'bridge')
    safe = float(bridge.get('safe_position_m', 0.0) or 0.0)
    meas = bagio.step_arrays(bag, topics.MEASUREMENT, ('applied', 'displacement', 'force'))
    order = np.argsort(meas['step'], kind='stable')
    meas = {k: np.asarray(v)[order] for k, v in meas.items()}
    steps = meas['step']
    state = np.array([status.get(int(k), ACTIVE) for k in steps])
    inferred = False
    if not np.any(state == STOPPED) and status and steps.size and meas['applied'].shape[1]:
        last_status = status[max(status)]
        if last_status != ACTIVE and float(meas['applied'][-1, 0]) == safe:
            state = np.where(steps > max(status), last_status, state)
            state[-1] = STOPPED
            inferred = True
    if not np.any(state == STOPPED):  # STOPPED after the last recorded measurement
        return None

    def channel0(table):
        return table[:, 0] if table.shape[1] else np.full(steps.size, np.nan)

    from rths_review.review import EXTERNAL, controller_counts, external_controller

    fs = bagio.sampling_rate(bag)
    numerical = runinfo.section(info, 'numerical')
    external = external_controller(bridge)
    summary = {
        'record': numerical.get('record'), 'scale': numerical.get('scale'),
        'specimen': EXTERNAL if external else specimen_of(bridge),
        'specimen_label': external or specimen_of(bridge),
        'force_scale': numerical.get('force_scale'),
        'actuator_model': bridge.get('actuator_model'), 'mode': info.get('mode'),
        'fs_hz': fs, 'compensator': runinfo.section(info, 'compensator'),
    }
    summary.update(safety_stop_summary(
        steps, state, faults[0], channel0(meas['applied']), channel0(meas['displacement']),
        channel0(meas['force']), fs, safe))
    summary['stop_inferred'] = inferred
    summary['safety_faults'] = faults
    summary['damper'] = summary['specimen']   # the former name of the key, kept for a while
    counts = controller_counts(bag)
    if counts is not None:
        summary['controller'] = counts
    return summary


def safety_stop_text(s: dict) -> str:
    """Return the printed report of a run stopped by the bridge's safety supervisor."""
    scheme = (s.get('compensator') or {}).get('scheme', '?')

    def metres(value, spec):
        return 'none' if value is None else f'{value:{spec}} m'

    from rths_review.report_html import specimen_title
    from rths_review.review import controller_text

    lines = [
        f"RTHS ABORTED by the bridge's safety supervisor: {s['record']} x {s['scale']}, "
        f"specimen {specimen_title(s)} x {s['force_scale']}, {s['mode']}, compensator {scheme}",
        f"  safety stop: {s['safety_stop']}",
        f"  fault at step {s['fault_step']} ({s['fault_time_s']:.3f} s); hold, ramp to the safe "
        f"position {s['safe_position_m']:g} m; " + (
            f"the bag ends at step {s['stop_step']} ({s['stop_time_s']:.3f} s) with the command "
            'at the safe position, before the STOPPED status reached it (inferred stop; the '
            'recorder lagged the loop)' if s.get('stop_inferred') else
            f"STOPPED at step {s['stop_step']} ({s['stop_time_s']:.3f} s)"),
        f"  steps run: {s['steps']}" + (f" of {s['planned_steps']} planned"
                                        if s.get('planned_steps') else ''),
        f"  final command {metres(s['final_command_m'], '.3g')}, measured displacement "
        f"{metres(s['final_displacement_m'], '.3g')}; largest command "
        f"{metres(s['max_abs_command_m'], '.4g')}",
        f"  largest |force| before the fault {s['max_abs_force_before_fault_n']:.1f} N; "
        'RMS force oscillation per second before it [N]:',
        '    ' + ' '.join(f'{v:.0f}' for v in s['force_rms_per_s_n']),
    ]
    if len(s.get('safety_faults', [])) > 1:
        lines.append('  further faults: ' + '; '.join(s['safety_faults'][1:]))
    if 'realtime_ok' in s:
        from rths_review.realtime import realtime_text
        lines.append('  ' + realtime_text(s))
    if s.get('controller'):
        lines.append('  ' + controller_text(s['controller']))
    return '\n'.join(lines) + '\n'


def bridge_params(bridge: dict, args, config: Path) -> dict:
    """Return the bridge's params of a run: the simulated plant's specimen, or a controller.

    ``--backend udp --controller HOST:PORT``: the simulated plant's keys of the
    config are dropped (the lab's controller has its own actuator and specimen),
    the rest (limits, loop settings) are kept.
    """
    from rths_actuator_bridge.safety import SAFETY_PARAMS
    from rths_actuator_bridge.simulated import SIM_PARAMS
    from rths_numerical.specimens import specimen_params

    bridge = renamed(bridge, 'dtm', 'specimen', str(config / 'bridge.yaml'))
    pairs = args.specimen_param + ([f'mr_voltage_v={args.mr_voltage}']
                                   if args.mr_voltage is not None else [])
    if args.backend == 'simulated':
        if args.controller:
            raise ValueError('--controller needs --backend udp')
        explicit = args.specimen is not None
        args.specimen = resolve_specimen(args.specimen, bridge, config / 'bridge.yaml')
        if args.specimen.startswith('tcp://'):
            return remote_bridge(bridge, args.specimen)
        if not explicit and args.specimen not in SPECIMENS.names():
            SPECIMENS.entry(args.specimen, f"{config / 'bridge.yaml'}: specimen")
        settings = specimen_settings(args.specimen, pairs, '--specimen-param')
        for key, value in settings.items():
            if key in bridge and bridge[key] != value:
                _say(f"note: {key}={value} (--specimen-param) overrides {key}: {bridge[key]} "
                     f"of {config / 'bridge.yaml'}")
        return dict(bridge, backend='simulated', specimen=args.specimen, **settings)
    if args.specimen is not None or pairs:
        raise ValueError('--specimen/--specimen-param/--mr-voltage: with --backend udp the '
                         "specimen is the controller's; drop them")
    host, sep, port = str(args.controller or '').rpartition(':')
    if not args.controller or not sep or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ValueError(f'--backend udp needs --controller HOST:PORT (got '
                         f'{args.controller!r}), e.g. 127.0.0.1:5005')
    simulated = {*SIM_PARAMS, *specimen_params()[0]} - set(SAFETY_PARAMS)
    kept = {k: v for k, v in bridge.items() if k not in simulated}
    return dict(kept, backend='udp', host=host or '127.0.0.1', port=int(port))


def resolve_specimen(option, bridge: dict, where) -> str:
    """Return the run's specimen: ``--specimen`` when given, else the config's, else the default.

    An explicit option that differs from the config file's ``specimen`` wins, and the
    conflict is printed (a note naming both and the file), never silently resolved.
    """
    configured = bridge.get('specimen')
    if option is None:
        return str(configured) if configured is not None else DEFAULT_SPECIMEN
    if configured is not None and str(configured) != option:
        _say(f'note: --specimen {option} overrides specimen: {configured} of {where}')
    return option


def remote_bridge(bridge: dict, site: str) -> dict:
    """Return the bridge parameters for a remote site ``tcp://host:port`` as the specimen.

    The node's own keys, the safety limits and the loop rate stay; the local
    plant's keys go (the specimen is the site's); ``backend: genericclient``.
    """
    from rths_actuator_bridge.bridge import PARAMS
    from rths_actuator_bridge.genericclient import parse_site
    from rths_actuator_bridge.safety import SAFETY_PARAMS
    from rths_common.params import NODE_KEYS
    parse_site(site)
    keep = {k: v for k, v in bridge.items() if k in NODE_KEYS or k in SAFETY_PARAMS
            or k in PARAMS}
    return dict(keep, backend='genericclient', site=site)


def _identity(fs: float) -> dict:
    """Return the identity compensator's filter fields at ``fs`` [Hz] (no provenance)."""
    return {k: v for k, v in identity_params(fs).items() if k != PROVENANCE}


class _RemoteOr(tuple):
    """The registry's specimen names as ``--specimen`` choices; a ``tcp://`` site is one too."""

    def __contains__(self, value):
        return str(value).startswith('tcp://') or tuple.__contains__(self, value)


def _specimen_arg(value: str) -> str:
    """Return ``--specimen``; a ``tcp://host:port`` is checked here (names by the choices)."""
    import argparse
    if str(value).startswith('tcp://'):
        from rths_actuator_bridge.genericclient import parse_site
        try:
            parse_site(value)
        except ValueError as err:
            raise argparse.ArgumentTypeError(str(err)) from None
    return value


def _model_param(model: str, config: Path) -> str:
    """Return the numerical node's ``model``: a shipped script name becomes its path."""
    if model in ('building2story', 'sdof') or model.endswith(('.yaml', '.yml', '.py')):
        return str(Path(model).resolve()) if model.endswith(('.yaml', '.yml', '.py')) else model
    script = config / 'models' / (model.replace('-', '_') + '.py')
    if not script.is_file():
        shipped = sorted(p.stem.replace('_', '-') for p in (config / 'models').glob('*.py'))
        raise ValueError(f'--model {model}: no such model; use building2story, a model YAML, '
                         f'a .py OpenSeesPy script or one of {", ".join(shipped) or "(none)"} '
                         f'({config / "models"})')
    return str(script.resolve())


def _identify_args(args) -> list:
    """Return the ``rths identify`` options of ``rths run``'s identification choices."""
    out = ['--method', args.ident_method]
    for flag, value in (('--na-max', args.ident_na_max), ('--nb-max', args.ident_nb_max),
                        ('--d-min', args.ident_d_min), ('--d-max', args.ident_d_max)):
        if value is not None:
            out += [flag, str(value)]
    return out


def _check_fit(plant, accept: bool) -> None:
    """Stop before the RTHS phase when the identified plant's validation fit is poor."""
    import yaml

    from rths_compensator.estimation import is_poor_fit, poor_fit_text
    doc = yaml.safe_load(Path(plant).read_text()) or {}
    validation = (doc.get('selection') or {}).get('validation')
    if not validation or not is_poor_fit(validation):
        return
    text = poor_fit_text(validation)
    if accept:
        _say(f'WARNING: {text} (--accept-poor-fit: running the RTHS anyway)')
        return
    raise RuntimeError(f'identified plant {plant}: {text}; the RTHS was not started, so the '
                       'specimen was not driven (see the fit plot beside it; '
                       '--accept-poor-fit runs it anyway)')


def cmd_run(args) -> int:
    """``rths run``."""
    from rths_bringup.commands import live_rate_of
    from rths_live import live

    if not args.out:
        args.out = str(Path('out') / ('run-' + datetime.datetime.now().strftime('%Y%m%d-%H%M%S')))
    try:
        # the run's ROS domain is held from the first phase to the last (the live view joins it)
        with isolation.reserved(f'rths run --out {Path(args.out).resolve()}'), \
                live.session(args, fs_hz=live_rate_of(args.config) if args.live else 0.0):
            return _run(args)
    except RuntimeError as err:
        print(f'rths run: error: {err}', file=sys.stderr)
        return 1


def _run(args) -> int:
    from rths_bringup.cli import main as rths_main
    from rths_review.review import print_review

    limits = limits_of(args)
    if args.force_scale is not None and not args.force_scale > 0:
        raise ValueError(f'--force-scale must be > 0 (specimens the one in the lab stands for), '
                         f'got {args.force_scale}')
    config = Path(args.config) if args.config else default_config_dir()
    out = Path(args.out)
    if out.exists() and any(out.iterdir()):
        raise OSError(f'results directory {out} exists and is not empty; choose a new --out')
    out.mkdir(parents=True, exist_ok=True)
    base = {node: runinfo.load_params(config / fname, node) for node, fname in NODE_FILES.items()}
    fs = float(base['numerical'].get('fs_hz', 1024.0))
    base['bridge'] = bridge_params(dict(base['bridge'], fs_hz=fs), args, config)
    remote = base['bridge'].get('backend') == 'genericclient'
    if remote:   # a remote site: its own specimen, actuator and compensator
        args.no_compensation = True
    model_param = _model_param(args.model, config)   # bad names fail before the long phases
    if args.specimen_model is not None and not Path(args.specimen_model).is_file():
        raise OSError(f'--specimen-model {args.specimen_model}: no such file')
    if args.numerical == 'opensees':
        from rths_numerical.opensees_backend import import_opensees
        import_opensees()
    _say(f'results in {out}')
    numerical = _numerical_params(args, base['numerical'], model_param, base['bridge'], remote)
    settings = _check_inputs(numerical, out, base['bridge'], args.output_dof)   # before all

    # 1-2: identification and design
    comp_file = out / 'compensator.yaml'
    if args.no_compensation:
        runinfo.write_params(comp_file, 'compensator', _identity(fs))
        _say(f'remote site {args.specimen}: identity taps here (the site compensates its own '
             'actuator)' if remote else 'no compensation: identity taps')
    else:
        plant = Path(args.plant) if args.plant else out / 'plant.yaml'
        if not args.plant:
            ident = out / 'identification'
            _identification_run(args, base, fs, ident, out, config)
            _say('step 2: identification (rths identify)')
            code = rths_main(['identify', '--bag', str(ident / 'bag'), '--out', str(plant)]
                             + _identify_args(args))
            if code:
                raise RuntimeError('identification failed')
            _check_fit(plant, args.accept_poor_fit)
        fc = ['--fc', str(args.fc)] if args.fc is not None else []
        _say(f'step 2: design {args.scheme} n={args.taps} '
             + (f'fc={args.fc} Hz' if fc else 'fc by the lag the FIR predicts') + ' (rths design)')
        code = rths_main(['design', '--plant', str(plant), '--scheme', args.scheme,
                          '--taps', str(args.taps), *fc,
                          '--limits', str(config / 'bridge.yaml'), '--out', str(comp_file)])
        if code:
            raise RuntimeError('compensator design failed')
        _say(f'compensator written to {comp_file} (install it as the lab\'s taps with '
             f'rths install-taps {out})')
    comp = runinfo.load_params(comp_file, 'compensator')
    comp.update({k: base['compensator'][k] for k in ('executor',) if k in base['compensator']})
    if METHODS.entry(args.adaptive).adaptive:
        if args.no_compensation:
            raise ValueError(f'--adaptive {args.adaptive} needs a designed FIR (drop '
                             '--no-compensation)')
        provenance = dict(comp.get('provenance') or {})
        provenance['plant'] = str(Path(str(provenance.get('plant', ''))).resolve())
        comp.update(method=args.adaptive, provenance=provenance)
    elif args.adaptive != METHOD_DEFAULT:
        comp.update(method=args.adaptive)

    # 3: the RTHS run
    rths_dir = out / 'rths'
    cfg = _phase_config(rths_dir, {'numerical': numerical, 'compensator': comp,
                                   'bridge': base['bridge']})
    stop = _launch_phase('RTHS', cfg, rths_dir / 'bag', 'rths', fs, args.mode,
                         {'numerical': numerical, 'bridge': base['bridge'],
                          'compensator': {'scheme': comp['scheme'], **{
                              k: v for k, v in comp.get('provenance', {}).items()
                              if k in ('n_taps', 'fc_hz', 'plant', 'predicted_delay_ms')},
                              'method': args.adaptive}},
                         history=rths_dir / 'numerical_history.npz', storage=args.storage,
                         live=args.live, layout=args.layout)
    if stop is not None:
        return _report_safety_stop(stop, numerical, out, rths_dir / 'bag', limits)
    record = settings['record_summary'] or {}
    _write_response(rths_dir / 'numerical_history.npz', record.get('t0_s', 0.0),
                    out / 'response.csv')

    # 4: review
    _say('step 4: review')
    summary = _review(rths_dir / 'bag', out, limits, args.specimen_model, args.output_dof)
    summary['adaptive'] = args.adaptive
    summary.setdefault('run_settings', {k: v for k, v in settings.items()
                                        if k != 'record_summary'})
    (out / 'summary.json').write_text(json.dumps(summary, indent=2))
    print_review(summary)
    _say(f'results: {out}/report.html (one file), {out}/summary.json, {out}/review.txt, '
         f'plots {out}/*.png, '
         f'bags {out}/*/bag')
    return 0


def identification_numerical(args, base_numerical: dict, fs: float) -> dict:
    """Return the identification run's numerical parameters (the excitation, not the building).

    Only the excitation's own keys apply.  Its own dict, never the RTHS phase's: from
    2026-11-25 to this fix the RTHS phase reused this one (a reassigned variable), so
    ``rths run`` drove the 0-64 Hz identification excitation through the compensator
    designed for 0-10 Hz instead of the building (test_delay_line's "70 Hz oscillation").
    """
    return {'mode': args.mode, 'executor': base_numerical.get('executor', 'events'),
            'model': 'excitation', 'fs_hz': fs, 'duration_s': float(args.ident_duration),
            'excitation_band_hz': 64.0, 'excitation_peak_m': 0.00254, 'seed': 7}


def _identification_run(args, base: dict, fs: float, ident: Path, out: Path, config: Path):
    """Step 1: the identification run (the excitation through the identity compensator)."""
    excitation = identification_numerical(args, base['numerical'], fs)
    cfg = _phase_config(ident, {
        'numerical': excitation, 'bridge': base['bridge'],
        'compensator': {**base['compensator'], **_identity(fs)}})
    stop = _launch_phase('identification', cfg, ident / 'bag', 'identification', fs,
                         args.mode, {'numerical': excitation, 'bridge': base['bridge']},
                         storage=args.storage, live=args.live, layout=args.layout)
    if stop is not None:
        _write_identification_stop(stop, out)
        raise RuntimeError(f'the identification run ended in the bridge\'s safety stop '
                           f'({stop["safety_stop"]}); check the excitation against the '
                           f'limits in {config / "bridge.yaml"}')


def _numerical_params(args, base: dict, model_param: str, bridge: dict, remote: bool) -> dict:
    """Return the RTHS run's numerical parameters: the config's, then every option given.

    No demo value reaches a lab's data: the scale is 1 for a record file (the
    seed's factor for its own records) and the force scale 1 for any model but
    the seed's building (5: one DTM stands for five, seed 6.2), unless given.
    """
    record = str(args.record)
    scale = args.scale if args.scale is not None else SEED_SCALES.get(record.lower(), 1.0)
    force_scale = (args.force_scale if args.force_scale is not None
                   else 5.0 if model_param == 'building2story' else 1.0)
    numerical = dict(base, model=model_param, record=record, scale=float(scale),
                     force_scale=float(force_scale), backend=args.numerical,
                     record_format=args.record_format, record_units=args.record_units,
                     record_dt_s=float(args.record_dt), record_resample=not args.no_resample,
                     record_remove_mean=not args.no_mean_removal,
                     record_baseline=not args.no_baseline,
                     # the frame the table must follow, and the specimen's mass for P_I^E
                     # (a controller's or a remote site's specimen: the numerical config's own)
                     **({} if remote or args.backend != 'simulated' else
                        SPECIMENS[args.specimen].numerical_params(bridge)))
    if args.numerical == 'opensees':
        numerical['integrator'] = 'central_difference'   # the RTHS pairing (README)
    for key in ('sdof_mass_kg', 'sdof_freq_hz', 'sdof_zeta', 'harmonic_freq_hz'):
        numerical.pop(key, None)
    numerical['duration_s'] = float(args.duration)
    return numerical


def _check_inputs(numerical: dict, out: Path, bridge: dict, output_dof=None):
    """Build the numerical substructure once (every input checked) and report the record.

    Prints the record as read (first and last samples, duration, rate, peak) and as
    the run will use it (its processing), and what shapes the run (scale, force
    scale, interface frame, model and its DOFs); writes them to ``OUT/inputs.json``.
    """
    from rths_common.params import core_params
    from rths_numerical.ground_motion import read_record
    from rths_numerical.substructure import make_substructure

    sub = make_substructure(core_params(numerical))
    specimen = specimen_of(bridge)
    entry = SPECIMENS.get(specimen) if bridge.get('backend', 'simulated') == 'simulated' else None
    if entry is not None:   # a simulated specimen (a controller's or a site's is their own)
        entry.check(bridge, sub.n_interface, f'model {getattr(sub.model, "name", "")}')
    settings = run_settings(numerical, sub)
    if output_dof is not None:
        from rths_review.review import dof_index
        dof_index(sub.model, output_dof, '--output-dof')
    settings['specimen'] = specimen
    settings['specimen_settings'] = entry.settings(bridge) if entry is not None else {}
    lines = ['inputs of the RTHS run:']
    if sub.motion is not None and sub.motion.fmt != 'synthetic':
        raw = read_record(numerical['record'], numerical.get('record_format', ''),
                          numerical.get('record_units', ''), numerical.get('record_dt_s', 0.0))
        lines.append('  as read:  ' + raw.describe().replace('\n', '\n  '))
        settings['record_as_read'] = raw.summary()
        del settings['record_as_read']['processing']
    if sub.motion is not None:
        lines.append('  as used:  ' + sub.motion.describe().replace('\n', '\n  '))
    lines.append(f"  specimen {specimen} {settings['specimen_settings'] or ''}".rstrip())
    lines.append(f"  scale {settings['scale']:g}, force scale {settings['force_scale']:g}, "
                 f"interface frame {settings['interface_frame']}, model "
                 f"{settings['model_name']} ({len(settings['dof_names'])} DOFs: "
                 f"{', '.join(settings['dof_names'])}), interface DOF(s) "
                 f"{', '.join(settings['interface_dof_names'])}")
    for line in lines:
        _say(line)
    (out / 'inputs.json').write_text(json.dumps(settings, indent=2))
    return settings


def run_settings(numerical: dict, sub) -> dict:
    """Return every value that shapes a run's numerical side, as the summary states it."""
    model = sub.model
    names = list(getattr(model, 'dof_names', []) or [])
    return {
        'record': numerical.get('record'), 'scale': float(numerical.get('scale', 1.0)),
        'force_scale': float(sub.force_scale), 'interface_frame': sub.frame,
        'specimen_mass_kg': float(getattr(sub, 'specimen_mass', 0.0)),
        'input_processing': list(sub.motion.processing) if sub.motion is not None else [],
        'model_name': getattr(model, 'name', str(numerical.get('model'))),
        'dof_names': names,
        'interface_dof_names': [names[i] if i < len(names) else str(i) for i in sub.iface],
        'record_summary': sub.motion.summary() if sub.motion is not None else None,
        # loop steps per numerical step (rths_numerical.multirate; 1: every loop step)
        'rate_divisor': int(getattr(sub, 'divisor', 1)),
    }


def _write_response(history: Path, t0: float, path: Path):
    """Write ``response.csv`` (time, ground acceleration, every DOF) from the run's history."""
    import numpy as np

    from rths_numerical.inputs import response_columns, write_response_csv

    if not history.is_file():
        return
    hist = np.load(history)
    disp = hist['displacements']
    table = np.column_stack([t0 + hist['time'], hist['ground_accel'], disp])
    write_response_csv(path, response_columns(disp.shape[1]), table)
    _say(f'response of every DOF: {path}')


def _report_safety_stop(stop: dict, numerical: dict, out: Path, bag: Path,
                        limits=None) -> int:
    """Write and print the summary of an RTHS run the bridge stopped; return EXIT_SAFETY_STOP."""
    _say('step 4: review of the run up to the safety stop')
    print(_write_stop_review(stop, numerical, out, bag, limits), end='', flush=True)
    _say(f'results: {out}/report.html, {out}/summary.json, {out}/review.txt, bag {bag}; '
         f'exit code {EXIT_SAFETY_STOP} (safety stop)')
    return EXIT_SAFETY_STOP


def _write_stop_review(stop: dict, numerical: dict, out: Path, bag: Path, limits=None,
                       tables: bool = True) -> str:
    """Write summary.json, review.txt and report.html of a run the bridge stopped; return the text.

    Tables 5-9 of what ran before the fault when it ran 2 s, else (or with ``tables``
    False: the caller's review found it too short already) the stop alone.
    """
    from rths_common.params import core_params
    from rths_numerical.substructure import make_substructure
    from rths_review.report_html import write_report, write_stop_report
    from rths_review.review import review_text
    from rths_review.tracking import REALTIME_KEYS, bridge_realtime, read_loop

    stop['planned_steps'] = int(make_substructure(core_params(numerical)).n_steps)
    stop['bag'] = str(bag)
    if stop.get('mode') == 'realtime':
        timing = bridge_realtime(read_loop(bag)['status'].get('bridge', {}),
                                 stop['planned_steps'], stop['fs_hz'], limits)
        stop.update({key: timing[key] for key in REALTIME_KEYS})
    stop['cut_short'] = stop['steps'] < stop['planned_steps']
    text = safety_stop_text(stop)
    # the review of what ran before the fault (tables 5-9 need 2 s of it)
    summary = None
    try:
        if tables:
            summary = _review(bag, out, limits)
    except ValueError as err:
        _say(f'no tables 5-9: {err}')
    if summary is None:
        (out / 'summary.json').write_text(json.dumps(stop, indent=2))
        (out / 'review.txt').write_text(text)
        write_stop_report(out, stop, text)
    else:
        # the stop's own figures win (steps: the steps run); the review's count stays beside
        summary = {**summary, 'reviewed_steps': summary['steps'], **stop}
        (out / 'summary.json').write_text(json.dumps(summary, indent=2))
        text = text + '\n' + review_text(summary)
        (out / 'review.txt').write_text(text)
        write_report(out, summary)
    return text


def _write_identification_stop(stop: dict, out: Path) -> None:
    """Write summary.json, review.txt and report.html of an identification run's safety stop.

    No RTHS ran, so no tables; the files say which phase stopped, where and why.
    """
    from rths_review.report_html import write_stop_report

    stop = dict(stop, phase='identification', record='identification excitation (BLWN)',
                scale=1.0)
    text = 'IDENTIFICATION ' + safety_stop_text(stop)
    (out / 'summary.json').write_text(json.dumps(stop, indent=2))
    (out / 'review.txt').write_text(text)
    write_stop_report(out, stop, text)
    _say(f'identification stopped: {out}/summary.json, {out}/review.txt, {out}/report.html')


def _review(bag, out, limits=None, specimen_model=None, dof=None) -> dict:
    """Run :func:`rths_review.review.review_rths` with a progress line over its stages."""
    from rths_common.progress import Progress
    from rths_review.review import REVIEW_STAGES, review_rths

    if specimen_model is not None and not Path(specimen_model).is_file():
        raise OSError(f'--specimen-model {specimen_model}: no such file')
    with Progress(REVIEW_STAGES, 'review', 'stages') as bar:
        return review_rths(bag, out, progress=bar.report, limits=limits,
                           specimen_model=specimen_model, dof=dof)


def cmd_review(args) -> int:
    """``rths review``."""
    from rths_common import bagio
    from rths_review.review import print_review
    from rths_review.tracking import TooShortError

    bag = Path(args.bag)
    out = Path(args.out) if args.out else bag.parent
    if not bagio.bag_dir(bag).is_dir():
        raise OSError(f'bag directory {bag} does not exist')
    limits = limits_of(args)
    info = bagio.run_info(bag)   # a damaged bag is refused before anything is written
    try:
        summary = _review(bag, out, limits, args.specimen_model, args.dof)
    except TooShortError as err:
        # a run the bridge stopped early (a fault; its supervisor killed): the stop's report,
        # as rths run would have written it; a short run that did not stop is refused (and
        # so is a site's: its model ran in the client, the planned steps are not in the bag)
        numerical = runinfo.section(info, 'numerical')
        stop = read_safety_stop(bag) if numerical else None
        if stop is None:
            raise
        _say(f'no tables 5-9: {err}')
        print(_write_stop_review(stop, numerical, out, bag, limits, tables=False), end='',
              flush=True)
        print(f'wrote {out}/report.html, {out}/summary.json and {out}/review.txt (the run '
              'stopped before 2 s of it could be reviewed: no tables 5-9)')
        return 0
    print_review(summary)
    print(f'wrote {out}/report.html, {out}/summary.json, {out}/review.txt and plots')
    return 0
