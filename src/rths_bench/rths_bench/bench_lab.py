"""``rths bench lab-faults``: issue 30's two lab checks, repeated, with their figures.

1. ``--runs`` N times ``rths run --mode realtime --layout processes --duration D --out P``
   (the identification included unless ``--plant`` is given): does every run end
   with a review (``P/summary.json`` and ``P/report.html``), whatever happened
   (completed, safety stop, a recording with gaps)?
2. ``--kills`` N times per layout (composed, processes): ``rths run --mode realtime
   --plant PLANT`` SIGKILLed at a random moment ``--kill-from``..``--kill-to`` s after
   the RTHS clock started; how long until no process of that run is left (every
   process whose environment names the killed launcher, rths_common.lifeline), does
   the bag close readable, does the bridge's last state read STOPPED with the last
   command at the safe position, and does ``rths review`` review it (or refuse in
   one line)?

Prints one line per run and writes ``{runs: {...}, kills: {composed: {...},
processes: {...}}, load: [...]}`` to ``--out``.  Timing figures are upper bounds
on a loaded machine: the load average is recorded before and after.

Imports of the commands' code sit in the command functions (``rths`` imports
this module to build its parser).
"""

import json
import os
from pathlib import Path
import random
import shutil
import signal
import subprocess
import tempfile
import threading
import time

import numpy as np

#: The line of the bridge that starts the RTHS clock (the kill's time origin).
CLOCK_STARTED = 'first command: clock started'
HOLD, RAMP, STOPPED = 1, 2, 3


def register(commands, benches):
    """Add ``rths bench lab-faults``."""
    p = benches.add_parser(
        'lab-faults', help="issue 30's lab checks: processes-layout runs reviewed, "
                           'supervisor SIGKILLs',
        description='Repeats the two checks of issue 30 and prints their figures: --runs '
                    'realtime runs in the processes layout (each must end with summary.json '
                    'and report.html) and --kills SIGKILLs of rths run per layout at a random '
                    'moment of the RTHS (no process of the run left within 1 s, the bag '
                    'closed and readable, the actuator ramped to its safe position, the bag '
                    'reviewable). Writes {runs, kills, load} to --out.')
    p.add_argument('--out', required=True, help='output JSON file')
    p.add_argument('--runs', type=int, default=10, help='processes-layout runs (default 10)')
    p.add_argument('--kills', type=int, default=5, help='kills per layout (default 5)')
    p.add_argument('--duration', type=float, default=20.0, help='run length [s] (default 20)')
    p.add_argument('--plant', default=None,
                   help='identified plant for the --runs (skips their identification run; '
                        'default: none, the whole rths run). The kills always use the '
                        "repo's config/plant.yaml")
    p.add_argument('--kill-from', type=float, default=0.7,
                   help='earliest kill after the RTHS clock started [s] (default 0.7)')
    p.add_argument('--kill-to', type=float, default=11.5,
                   help='latest kill after the RTHS clock started [s] (default 11.5)')
    p.add_argument('--seed', type=int, default=30, help='seed of the kill moments')
    p.add_argument('--keep', default=None,
                   help='keep the run directories here (each of the --runs with what rths run '
                        'printed, in rths_run.log)')
    p.set_defaults(func=_cmd)


def _rths() -> str:
    path = shutil.which('rths')
    if path is None:
        raise OSError("the rths command is not on PATH; run 'source env.sh'")
    return path


def run_processes(launcher_pid: int) -> list:
    """Pids of the live processes whose environment names ``launcher_pid`` as their launcher."""
    key = f'RTHS_LAUNCHER_PID={launcher_pid}'.encode()
    pids = []
    for entry in os.listdir('/proc'):
        if not entry.isdigit():
            continue
        try:
            with open(f'/proc/{entry}/environ', 'rb') as f:
                env = f.read().split(b'\0')
            with open(f'/proc/{entry}/stat') as f:
                state = f.read().rsplit(')', 1)[1].split()[0]
        except OSError:
            continue
        if key in env and state != 'Z':          # a zombie has ended
            pids.append(int(entry))
    return pids


def one_run(out: Path, duration: float, plant) -> dict:
    """One ``rths run`` in the processes layout: its exit code and whether it was reviewed."""
    cmd = [_rths(), 'run', '--mode', 'realtime', '--layout', 'processes',
           '--duration', f'{duration:g}', '--out', str(out)]
    if plant:
        cmd += ['--plant', str(plant)]
    t0 = time.monotonic()
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if out.is_dir():      # what the run printed, beside its results (--keep keeps it)
        (out / 'rths_run.log').write_text(proc.stdout + proc.stderr)
    r = {'exit_code': proc.returncode, 'wall_s': round(time.monotonic() - t0, 1),
         'summary_json': (out / 'summary.json').is_file(),
         'report_html': (out / 'report.html').is_file()}
    r['reviewed'] = r['summary_json'] and r['report_html']
    if r['summary_json']:
        s = json.loads((out / 'summary.json').read_text())
        r.update({k: s.get(k) for k in ('safety_stop', 'recording_complete',
                                        'recording_longest_gap_steps', 'recording_kept_pct',
                                        'late_or_missed_pct', 'realtime_ok', 'steps')})
    else:
        r['error'] = (proc.stderr.strip().splitlines() or [''])[-1][:300]
    return r


def _bag_end(bag: Path) -> dict:
    """Return the bag's state after a kill: readable, the bridge's last state, last command."""
    from rths_common import bagio, runinfo, topics

    r = {'bag_readable': False, 'last_state': None, 'last_command_at_safe': None,
         'ramp_recorded': None}
    try:
        status = [(int(m.step), int(m.safety_state))
                  for _, _, m in bagio.read_messages(bag, [topics.STATUS]) if m.node == 'bridge']
        meas = bagio.step_arrays(bag, topics.MEASUREMENT, ('applied',))
        bridge = runinfo.section(bagio.run_info(bag), 'bridge')
    except Exception as err:   # noqa: BLE001 -- any damage is the finding, said in one field
        r['bag_error'] = f'{type(err).__name__}: {err}'[:300]
        return r
    r['bag_readable'] = True
    if status:
        status.sort()
        states = {s for _, s in status}
        r['last_state'] = status[-1][1]
        r['ramp_recorded'] = HOLD in states and RAMP in states and STOPPED in states
    if len(meas['step']):
        last = float(meas['applied'][int(np.argmax(meas['step'])), 0])
        r['last_command_at_safe'] = last == float(bridge.get('safe_position_m', 0.0))
    return r


def one_kill(out: Path, layout: str, after_s: float, duration: float) -> dict:
    """SIGKILL ``rths run`` ``after_s`` after its RTHS clock started; what was left, how long."""
    from rths_bringup.commands import default_config_dir

    plant = default_config_dir() / 'plant.yaml'
    cmd = [_rths(), 'run', '--mode', 'realtime', '--layout', layout, '--duration',
           f'{duration:g}', '--plant', str(plant), '--out', str(out)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    r = {'layout': layout, 'kill_after_s': round(after_s, 2)}
    t_end = time.monotonic() + 300.0
    started = None
    for line in proc.stdout:
        if CLOCK_STARTED in line:
            started = time.monotonic()
            break
        if time.monotonic() > t_end:
            break
    if started is None:
        proc.kill()
        proc.wait()
        r['error'] = 'the RTHS clock did not start'
        return r
    drain = threading.Thread(target=proc.stdout.read, daemon=True)   # keep the pipe drained
    drain.start()
    while time.monotonic() - started < after_s and proc.poll() is None:
        time.sleep(0.01)
    r['children_at_kill'] = len(run_processes(proc.pid))
    r['run_ended_before_kill'] = proc.poll() is not None
    proc.send_signal(signal.SIGKILL)
    t0 = time.monotonic()
    proc.wait()
    while run_processes(proc.pid) and time.monotonic() - t0 < 10.0:
        time.sleep(0.005)
    r['gone_s'] = round(time.monotonic() - t0, 3)
    r['left_after_10s'] = len(run_processes(proc.pid))
    drain.join(2.0)
    bag = out / 'rths' / 'bag'
    r.update(_bag_end(bag))
    review = subprocess.run([_rths(), 'review', str(bag), '--out', str(out / 'review')],
                            capture_output=True, text=True, check=False)
    r['review_exit'] = review.returncode
    r['review_one_line_error'] = (review.returncode != 0 and review.stderr.count('\n') == 1
                                  and 'Traceback' not in review.stderr)
    r['reviewed'] = review.returncode == 0 and (out / 'review' / 'report.html').is_file()
    return r


def _cmd(args) -> int:
    rng = random.Random(args.seed)
    base = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix='rths-lab-faults-'))
    base.mkdir(parents=True, exist_ok=True)
    result = {'load_before': list(os.getloadavg()), 'runs': {}, 'kills': {},
              'duration_s': args.duration, 'seed': args.seed}
    try:
        runs = []
        for i in range(args.runs):
            r = one_run(base / f'run{i}', args.duration, args.plant)
            r['load'] = round(os.getloadavg()[0], 1)
            runs.append(r)
            print(f'run {i + 1}/{args.runs}: exit {r["exit_code"]}, reviewed {r["reviewed"]}, '
                  f'safety stop {r.get("safety_stop")}, recording complete '
                  f'{r.get("recording_complete")}, load {r["load"]}', flush=True)
        if runs:
            result['runs'] = {'runs': len(runs), 'reviewed': sum(r['reviewed'] for r in runs),
                              'safety_stops': sum(bool(r.get('safety_stop')) for r in runs),
                              'recordings_incomplete': sum(r.get('recording_complete') is False
                                                           for r in runs),
                              'details': runs}
        for layout in ('composed', 'processes'):
            kills = []
            for i in range(args.kills):
                after = rng.uniform(args.kill_from, args.kill_to)
                r = one_kill(base / f'kill_{layout}{i}', layout, after, args.duration)
                r['load'] = round(os.getloadavg()[0], 1)
                kills.append(r)
                print(f'kill {layout} {i + 1}/{args.kills} at {r["kill_after_s"]} s: gone in '
                      f'{r.get("gone_s")} s, bag readable {r.get("bag_readable")}, last state '
                      f'{r.get("last_state")}, at safe {r.get("last_command_at_safe")}, '
                      f'reviewed {r.get("reviewed")}, load {r["load"]}', flush=True)
            gone = [r['gone_s'] for r in kills if 'gone_s' in r]
            result['kills'][layout] = {
                'kills': len(kills), 'gone_s': gone, 'gone_s_max': max(gone, default=None),
                'within_1s': sum(g <= 1.0 for g in gone),
                'bags_readable': sum(bool(r.get('bag_readable')) for r in kills),
                'ended_stopped_at_safe': sum(r.get('last_state') == STOPPED
                                             and bool(r.get('last_command_at_safe'))
                                             for r in kills),
                'reviewed': sum(bool(r.get('reviewed')) for r in kills),
                'refused_in_one_line': sum(bool(r.get('review_one_line_error')) for r in kills),
                'details': kills}
    finally:
        result['load_after'] = list(os.getloadavg())
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(result, indent=2))
        if not args.keep:
            shutil.rmtree(base, ignore_errors=True)
    runs = result.get('runs') or {}
    if runs:
        print(f"processes layout: {runs['reviewed']} of {runs['runs']} runs reviewed "
              f"({runs['safety_stops']} safety stops, {runs['recordings_incomplete']} "
              'recordings with gaps)')
    for layout, k in result['kills'].items():
        print(f"kills {layout}: {k['within_1s']} of {k['kills']} gone within 1 s (max "
              f"{k['gone_s_max']} s), {k['bags_readable']} bags readable, "
              f"{k['ended_stopped_at_safe']} ended STOPPED at the safe position, "
              f"{k['reviewed']} reviewed, {k['refused_in_one_line']} refused in one line")
    print(f'load {result["load_before"][0]:.1f} before, {result["load_after"][0]:.1f} after; '
          f'wrote {args.out}')
    return 0
