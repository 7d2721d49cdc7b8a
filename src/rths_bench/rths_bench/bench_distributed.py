"""``rths bench distributed``: the realtime loop across an emulated lab network.

Each condition runs the realtime graph (simulated plant, the designed
compensator of ``config/compensator.yaml`` when its rate matches) with the
numerical node in ROS domain A and the compensator, the bridge and the
recorder in domain B, joined by the link relay ``rths linkemu``
(:mod:`rths_bench.linkemu`) with the condition's one-way delay, jitter and
loss.  With ``--netns`` (default when running as root) every node runs on its
own "host", a network namespace (:mod:`rths_bench.netns`), and DDS talks
UDP over veth links; the condition ``local`` is the reference without relay
(one domain, one host).

Per condition it reports the bridge's deadline misses (ticks without the
step's command: extrapolated), the relative RMS tracking error between the
interface displacement the numerical node asked for and the displacement the
actuator reached (``rms(x_m - x_t) / rms(x_t)``, same step), the final safety
state and whether the run completed.  The loop closes once per step: the
command of step k needs measurement k-1, so the round trip (2 x one-way
delay + compute) must fit in one period (0.98 ms at 1024 Hz); beyond that
every tick misses and the watchdog stops the run safely.  ``--delay-line auto``
runs each relayed condition with the bridge's delay line sized for its round
trip (:func:`delay_steps_for`), the compensator unchanged.

``rths bench absorb-delay`` (:func:`cmd_bench_absorb`): the bridge's delay
line (``command_delay_steps`` D) lets the round trip take D + 1 periods; an
identification run through the link with the same D puts the D steps into
the identified plant, and the compensator designed on it compensates them.
"""

import argparse
import json
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time

import numpy as np
import yaml

from rths_compensator.schemes import DEFAULT_SCHEME

# Imports of the commands' code sit in the command functions: rths imports this module
# to build its parser, and every rths command would pay for SciPy, matplotlib and ROS.

#: (name, one-way delay [ms], jitter [ms], loss [%]); 'local' = no relay.
CONDITIONS = (
    ('local', None, 0.0, 0.0),
    ('relay 0 ms', 0.0, 0.0, 0.0),
    ('delay 0.1 ms', 0.1, 0.0, 0.0),
    ('delay 0.5 ms', 0.5, 0.0, 0.0),
    ('delay 1 ms', 1.0, 0.0, 0.0),
    ('delay 2 ms', 2.0, 0.0, 0.0),
    ('delay 0.1 ms + jitter 0.2 ms', 0.1, 0.2, 0.0),
    ('delay 0.1 ms + loss 0.1 %', 0.1, 0.0, 0.1),
    ('delay 0.1 ms + loss 1 %', 0.1, 0.0, 1.0),
)
HOSTS = ('numerical', 'compensator', 'bridge', 'link')
#: The bridge's watchdog in these runs [steps]: 50 ms of extrapolation before a safe stop, so
#: a scheduling stall of the loaded test machine is counted (misses) rather than ending the run.
WATCHDOG_STEPS = 51


def rths_executable() -> str:
    """Return the path of the installed ``rths`` executable."""
    from ament_index_python.packages import get_package_prefix

    return str(Path(get_package_prefix('rths_bringup')) / 'lib' / 'rths_bringup' / 'rths')


def write_run_config(directory, rate_hz, duration_s, priority, taps_from=None) -> Path:
    """Realtime config (bench_loop.write_config) with the designed taps if the rate matches."""
    from rths_bench.bench_loop import write_config

    config = write_config(directory, rate_hz=rate_hz, duration_s=duration_s, taps=400,
                          model='sdof', priority=priority, watchdog_steps=WATCHDOG_STEPS)
    path = config / 'bridge.yaml'   # the limits of config/bridge.yaml (seed BLWN: 178 m/s^2)
    data = yaml.safe_load(path.read_text())
    data['bridge']['ros__parameters']['acceleration_m_s2'] = 400.0
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    if taps_from and Path(taps_from).is_file():
        src = yaml.safe_load(Path(taps_from).read_text())['compensator']['ros__parameters']
        if float(src.get('fs_hz', 0)) == float(rate_hz):
            path = config / 'compensator.yaml'
            data = yaml.safe_load(path.read_text())
            data['compensator']['ros__parameters'].update(
                taps=src['taps'], denominator=src.get('denominator', [1.0]),
                scheme=src.get('scheme', DEFAULT_SCHEME))
            path.write_text(yaml.safe_dump(data, sort_keys=False))
    return config


def bag_metrics(bag) -> dict:
    """Deadline misses, tracking error and safety state of a run's bag."""
    from rths_common import topics
    from rths_review.review import read_loop

    loop = read_loop(bag)
    target = dict(zip(loop['steps'][topics.INTERFACE_DISPLACEMENT]['step'],
                      loop['steps'][topics.INTERFACE_DISPLACEMENT]['values'], strict=True))
    meas_steps = loop['steps'][topics.MEASUREMENT]['step']
    bridge = loop['status'].get('bridge', {'step': [], 'misses': 0, 'safety_state': [0]})
    measured = {}
    for step, values in zip(meas_steps, read_measured(bag), strict=True):
        measured[step] = values
    common = sorted(set(target) & set(measured))
    xt = np.array([target[k][0] for k in common]) if common else np.zeros(1)
    xm = np.array([measured[k][0] for k in common]) if common else np.zeros(1)
    ok = np.isfinite(xm)
    rms_t = float(np.sqrt(np.mean(xt[ok] ** 2))) if ok.any() else 0.0
    err = float(np.sqrt(np.mean((xm[ok] - xt[ok]) ** 2)) / rms_t * 100) if rms_t else None
    ticks = len(bridge['step'])
    return {'ticks': ticks, 'deadline_misses': int(bridge['misses']),
            'miss_pct': round(100.0 * bridge['misses'] / ticks, 2) if ticks else None,
            'tracking_error_pct': None if err is None else round(err, 3),
            'steps_compared': len(common),
            'final_safety_state': int(bridge['safety_state'][-1]) if bridge['safety_state']
            else None,
            'faults': sorted(set(f.split(': ', 1)[-1] for f in bridge.get('faults', [])))[:3]}


def read_measured(bag):
    """Return the measured displacement of channel 0 of every step in ``bag``."""
    from rths_common import bagio, topics

    return [np.asarray(m.displacement, dtype=float)
            for _, _, m in bagio.read_messages(bag, [topics.MEASUREMENT])]


def run_condition(name, delay_ms, jitter_ms, loss_pct, config, workdir, net=None,
                  domains=(71, 72), seed=1, log=print, priority=0, mode='realtime',
                  timeout_s=120.0, delay_steps=0, label=None) -> dict:
    """One run of the graph under a link condition; the metrics of its bag.

    ``delay_steps`` > 0 runs the bridge with that delay line (``command_delay_steps``);
    ``label`` names the run's progress line (default ``name``).
    """
    from rths_bringup.commands import run_info_of
    from rths_bringup.launcher import Launcher

    bag = Path(workdir) / 'bag'
    relay = None
    dom_a, dom_b = domains
    overrides = {'bridge': {'command_delay_steps': int(delay_steps)}} if delay_steps else {}
    if delay_ms is None:      # the reference: one domain, one host
        node_env = {n: _env(net, 'link', dom_b) for n in ('numerical', 'compensator', 'bridge',
                                                          'recorder')}
        prefix = {n: (net.prefix('link') if net else []) for n in node_env}
    else:
        node_env = {'numerical': _env(net, 'numerical', dom_a),
                    'compensator': _env(net, 'compensator', dom_b),
                    'bridge': _env(net, 'bridge', dom_b), 'recorder': _env(net, 'bridge', dom_b)}
        prefix = {n: (net.prefix(h) if net else []) for n, h in
                  (('numerical', 'numerical'), ('compensator', 'compensator'),
                   ('bridge', 'bridge'), ('recorder', 'bridge'))}
        overrides['numerical'] = {'remote_graph': True, 'wait_for_subscribers': 1}
        env = dict(os.environ, **_env(net, 'link', dom_a))
        env.pop('ROS_DOMAIN_ID', None)
        argv = [*(net.prefix('link') if net else []), rths_executable(), 'linkemu',
                '--domain-a', str(dom_a), '--domain-b', str(dom_b), '--delay-ms', str(delay_ms),
                '--jitter-ms', str(jitter_ms), '--loss-pct', str(loss_pct), '--seed', str(seed),
                '--rt-priority', str(max(priority - 1, 0)), '--mode', mode,
                '--wait-readers', '2']
        relay = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                 text=True, env=env)
        lines = []
        while not lines or 'relaying' not in lines[-1]:
            lines.append(relay.stdout.readline())
            if not lines[-1] or len(lines) > 50:
                relay.kill()
                raise OSError('rths linkemu did not start: ' + ''.join(lines[-5:]).strip())
    # The recorder runs on the bridge's host, as a lab records at the controller, at nice 0:
    # best-effort samples it does not read in time are lost (on the link host at nice 10 it
    # recorded 692 of 8791 steps of a loaded 1024 Hz run).
    overrides['recorder'] = dict(run_info_of(config, overrides), nice=0)
    out = open(Path(workdir) / 'launch.log', 'w')
    t0 = time.monotonic()
    try:
        code = Launcher(config, bag=bag, overrides=overrides, out=out, timeout_s=timeout_s,
                        node_env=node_env, node_prefix=prefix,
                        progress_label=label or name).run()
    finally:
        out.close()
        link_stats = ''
        if relay is not None:
            relay.send_signal(2)
            try:
                link_stats = relay.communicate(timeout=10)[0].strip().splitlines()[-1:]
            except subprocess.TimeoutExpired:
                relay.kill()
    result = {'condition': name, 'one_way_delay_ms': delay_ms, 'jitter_ms': jitter_ms,
              'loss_pct': loss_pct, 'command_delay_steps': int(delay_steps),
              'launcher_exit': code, 'completed': code == 0,
              'wall_s': round(time.monotonic() - t0, 1), 'link': link_stats}
    result.update(bag_metrics(bag) if bag.exists() else {})
    log(f"{name:32s} misses {result.get('deadline_misses')!s:>6} of "
        f"{result.get('ticks')!s:>6} ({result.get('miss_pct')!s:>6} %), tracking error "
        f"{result.get('tracking_error_pct')!s:>8} %, completed {result['completed']}, "
        f"final safety state {result.get('final_safety_state')}")
    return result


def _env(net, host, domain):
    if net is None:
        return {'ROS_DOMAIN_ID': str(domain), 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
    return net.dds_env(host, domain)


def cmd_bench_distributed(args) -> int:
    """``rths bench distributed``."""
    from rths_bench import netns

    use_netns = args.netns
    if use_netns:
        reason = netns.available()
        if reason:
            raise OSError(f'--netns: cannot create network namespaces ({reason}); run as root '
                          'or use --no-netns')
    names = [c[0] for c in CONDITIONS]
    chosen = [c for c in CONDITIONS if not args.only or c[0] in args.only]
    if args.only and len(chosen) != len(args.only):
        raise ValueError(f'--only: unknown condition(s); choose from {names}')
    results = []
    with tempfile.TemporaryDirectory(prefix='rths-distributed-') as tmp:
        if args.keep:
            tmp = tempfile.mkdtemp(prefix='rths-distributed-')
            print(f'keeping configs, bags and logs in {tmp}')
        config = write_run_config(Path(tmp) / 'config', args.rate, args.duration, args.priority,
                                  args.taps)
        net = netns.LabNetwork(HOSTS, tag='bench').create() if use_netns else None
        try:
            for i, (name, delay, jitter, loss) in enumerate(chosen):
                work = Path(tmp) / f'run{i}'
                work.mkdir()
                steps = 0
                if args.delay_line == 'auto' and delay is not None:
                    steps = delay_steps_for(delay + jitter, args.rate)
                    name = f'{name}, D = {steps}'
                results.append(run_condition(name, delay, jitter, loss, config, work, net,
                                             domains=(args.domain, args.domain + 1),
                                             priority=args.priority, delay_steps=steps,
                                             label=f'[{i + 1}/{len(chosen)}] {name}'))
        finally:
            if net is not None:
                net.close()
    doc = {'rate_hz': args.rate, 'duration_s': args.duration, 'netns': use_netns,
           'rt_priority': args.priority, 'delay_line': args.delay_line, 'conditions': results,
           'note': 'deadline miss: the command of step k had not reached the bridge at tick k '
                   '(the bridge extrapolated); tracking error: rms(measured - interface '
                   'displacement) / rms(interface displacement), same step'}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(doc, indent=2))
    print(f'written {args.out}')
    return 0


# ------------------------------------------------------------------ delay absorption
#: Round-trip time of the loop beyond twice the one-way link delay [ms]: two relay hops
#: (measured ~0.38 ms each on this machine kind), the three nodes' compute and the tail:
#: through a 1 ms link the round trip was 2.5 ms median, 4.7 ms p99 on a loaded machine.
ROUND_TRIP_OVERHEAD_MS = 3.0


def delay_steps_for(one_way_ms: float, rate_hz: float) -> int:
    """D such that the round trip (2 x one-way + overhead) fits in D + 1 periods."""
    period_ms = 1000.0 / rate_hz
    return max(int(np.ceil((2.0 * one_way_ms + ROUND_TRIP_OVERHEAD_MS) / period_ms)) - 1, 0)


def _phase_config(directory, base, numerical=None, compensator=None, bridge=None) -> Path:
    """Copy the ``base`` config dir with the given params merged into the three files."""
    from rths_common import runinfo

    directory = Path(directory)
    for node, extra in (('numerical', numerical), ('compensator', compensator),
                        ('bridge', bridge)):
        params = runinfo.load_params(Path(base) / f'{node}.yaml', node)
        if node == 'numerical' and extra is not None:   # the model replaces the base's model
            params = {k: v for k, v in params.items() if k in (
                'mode', 'executor', 'rt_priority', 'cpus', 'gc', 'status_every', 'fs_hz')}
        params.update(extra or {})
        runinfo.write_params(directory / f'{node}.yaml', node, params)
    return directory


def _loop_tracking(bag) -> dict:
    """Delay (eq. 42, PSD-weighted) and relative RMS error, interface displacement -> measured."""
    from rths_common import bagio, topics
    from rths_compensator.indicators import relative_rms_pct
    from rths_review.tracking import weighted_delay_ms

    fs = bagio.sampling_rate(bag)
    disp = bagio.step_arrays(bag, topics.INTERFACE_DISPLACEMENT, ('displacement',))
    meas = bagio.step_arrays(bag, topics.MEASUREMENT, ('displacement',))
    target = dict(zip(disp['step'].tolist(), disp['displacement'][:, 0], strict=True))
    measured = zip(meas['step'].tolist(), meas['displacement'][:, 0], strict=True)
    pairs = [(target[k], m) for k, m in measured
             if k in target and np.isfinite(m)]
    if len(pairs) < 2 * fs:
        return {'delay_ms': None, 'tracking_rel_rms_pct': None}
    desired, measured = np.array(pairs).T
    return {'delay_ms': round(float(weighted_delay_ms(desired, measured, fs)), 3),
            'tracking_rel_rms_pct': round(float(relative_rms_pct(desired, measured)), 3)}


def _identify_and_design(workdir, base, link_ms, delay_steps, net, args, log) -> Path:
    """Identification run (BLWN) through the link, ARX identification, WLS design: the taps file."""
    from rths_bringup.cli import main as rths_main

    workdir = Path(workdir)
    config = _phase_config(
        workdir / 'config', base,
        numerical={'model': 'excitation', 'duration_s': float(args.ident_duration),
                   'excitation_band_hz': 64.0, 'excitation_peak_m': 0.00254, 'seed': 7},
        compensator={'scheme': 'identity', 'taps': [1.0], 'denominator': [1.0]},
        bridge={'command_delay_steps': int(delay_steps)})
    where = 'locally' if link_ms is None else f'through the link ({link_ms} ms one way)'
    log(f'identification run {where}, command_delay_steps {delay_steps}')
    result = run_condition('identification', link_ms, 0.0, 0.0, config, workdir, net,
                           domains=(args.domain, args.domain + 1), priority=args.priority,
                           log=log)
    if not result['completed']:
        raise RuntimeError(f'identification run {where} did not complete: {result}')
    plant, taps = workdir / 'plant.yaml', workdir / 'compensator.yaml'
    if rths_main(['identify', '--bag', str(workdir / 'bag'), '--out', str(plant)]):
        raise RuntimeError('rths identify failed')
    if rths_main(['design', '--plant', str(plant), '--scheme', DEFAULT_SCHEME, '--taps', '400',
                  '--fc', '10', '--out', str(taps)]):
        raise RuntimeError('rths design failed')
    return taps


def _rths_run(name, workdir, base, taps, link_ms, delay_steps, net, args, log) -> dict:
    """Run the building (Kobe) through the link with the given taps and delay line; metrics."""
    from rths_common import runinfo

    comp = runinfo.load_params(taps, 'compensator')
    config = _phase_config(
        Path(workdir) / 'config', base,
        numerical={'model': 'building2story', 'record': args.record, 'scale': args.scale,
                   'force_scale': 5.0, 'interface_frame': 'absolute', 'integrator': 'cr',
                   'duration_s': float(args.duration)},
        compensator={k: comp[k] for k in ('scheme', 'taps', 'denominator')},
        bridge={'command_delay_steps': int(delay_steps)})
    result = run_condition(name, link_ms, 0.0, 0.0, config, workdir, net,
                           domains=(args.domain, args.domain + 1), priority=args.priority,
                           log=log)
    result['command_delay_steps'] = int(delay_steps)
    bag = Path(workdir) / 'bag'
    if bag.exists():
        result.update(_loop_tracking(bag))
    log(f"{name:52s} delay {result.get('delay_ms')!s:>7} ms, error "
        f"{result.get('tracking_rel_rms_pct')!s:>7} %, misses {result.get('deadline_misses')}, "
        f"completed {result['completed']}")
    return result


def cmd_bench_absorb(args) -> int:
    """Identification through the network lets the compensator absorb its constant delay."""
    try:
        return _bench_absorb(args)
    except RuntimeError as err:
        print(f'rths bench absorb-delay: error: {err}', file=sys.stderr)
        return 1


def _bench_absorb(args) -> int:
    from rths_bench import netns

    use_netns = args.netns
    if use_netns and netns.available():
        raise OSError(f'--netns: cannot create network namespaces ({netns.available()}); run '
                      'as root or use --no-netns')
    d = float(args.one_way_ms)
    steps = args.delay_steps if args.delay_steps is not None else delay_steps_for(d, args.rate)

    def log(text):
        print(f'[absorb] {text}', flush=True)

    log(f'link {d} ms one way at {args.rate:g} Hz: command_delay_steps D = {steps} '
        f'(round trip budget {(steps + 1) * 1000.0 / args.rate:.2f} ms)')
    rows = []
    keep = tempfile.mkdtemp(prefix='rths-absorb-') if args.keep else None
    with tempfile.TemporaryDirectory(prefix='rths-absorb-') as tmp:
        tmp = Path(keep or tmp)
        base = write_run_config(tmp / 'base', args.rate, args.duration, args.priority)
        net = netns.LabNetwork(HOSTS, tag='absorb').create() if use_netns else None
        try:
            local_taps = _identify_and_design(tmp / 'ident_local', base, None, 0, net, args, log)
            link_taps = _identify_and_design(tmp / 'ident_link', base, d, steps, net, args, log)
            runs = (('local, compensator identified locally', None, 0, local_taps),
                    (f'link {d:g} ms, no delay line, local compensator', d, 0, local_taps),
                    (f'link {d:g} ms, D={steps}, local compensator', d, steps, local_taps),
                    (f'link {d:g} ms, D={steps}, identified through the link', d, steps,
                     link_taps))
            for i, (name, link, dsteps, taps) in enumerate(runs):
                work = tmp / f'rths{i}'
                work.mkdir()
                rows.append(_rths_run(name, work, base, taps, link, dsteps, net, args, log))
        finally:
            if net is not None:
                net.close()
    doc = {'rate_hz': args.rate, 'one_way_delay_ms': d, 'command_delay_steps': steps,
           'record': args.record, 'scale': args.scale, 'duration_s': args.duration,
           'netns': use_netns, 'runs': rows,
           'note': 'delay_ms and tracking_rel_rms_pct: interface displacement -> measured '
                   'actuator displacement of the same step (eq. 42 PSD-weighted, eq. 43); the '
                   'bridge writes the command of step k at tick k + D (command_delay_steps)'}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(doc, indent=2))
    log(f'written {args.out}')
    return 0


def register(commands, benches):
    """Add ``rths bench distributed`` and ``rths bench absorb-delay``."""
    p = benches.add_parser('distributed', help='realtime loop across an emulated lab network '
                           '(netns hosts, link delay/jitter/loss): misses and tracking error')
    p.add_argument('--out', required=True, help='JSON file to write')
    p.add_argument('--rate', type=float, default=1024.0, help='loop rate [Hz]')
    p.add_argument('--duration', type=float, default=5.0, help='simulated seconds per run')
    p.add_argument('--priority', type=int, default=80, help='SCHED_FIFO priority of the bridge')
    p.add_argument('--taps', default='',
                   help='compensator params file whose taps are used when their fs_hz matches '
                        "(default: a 400-tap unit-gain FIR; a designed FIR's large taps turn "
                        'one extrapolated step into a velocity-limit trip)')
    p.add_argument('--domain', type=int, default=71, help='ROS domain A (B is A + 1)')
    p.add_argument('--netns', action=argparse_bool(), default=os.geteuid() == 0,
                   help='run each node in its own network namespace (needs root)')
    p.add_argument('--keep', action='store_true', help='keep the bags and logs')
    p.add_argument('--only', nargs='*', help='run only these conditions (names as printed)')
    p.add_argument('--delay-line', choices=('off', 'auto'), default='off',
                   help="off: the bridge writes command k at tick k (the round trip must fit in "
                        "one period); auto: relayed conditions run with the bridge's delay line "
                        'D = command_delay_steps sized for the round trip (2 x (delay + jitter) '
                        f'+ {ROUND_TRIP_OVERHEAD_MS} ms in D + 1 periods), the compensator '
                        'unchanged (the D steps are not compensated: see absorb-delay)')
    p.set_defaults(func=cmd_bench_distributed)

    p = benches.add_parser(
        'absorb-delay', help='a constant network delay absorbed by the compensator: '
        'identification and RTHS through the emulated link, with the bridge delay line',
        description='Runs, at --rate: identification + design locally and through the link '
        '(one-way --one-way-ms, bridge command_delay_steps D), then the building (Kobe) four '
        'times: local; link without delay line (every tick misses: safe stop); link with D '
        'and the local compensator (D steps uncompensated); link with D and the compensator '
        'identified through the link (delay absorbed).  Prints and writes delay and tracking '
        'error of each.  Takes about 3 minutes.')
    p.add_argument('--out', required=True, help='JSON file to write')
    p.add_argument('--one-way-ms', type=float, default=1.0, help='one-way link delay [ms] (1)')
    p.add_argument('--delay-steps', type=int, default=None,
                   help='bridge command_delay_steps D (default: the round trip '
                        f'2 x one-way + {ROUND_TRIP_OVERHEAD_MS} ms in D + 1 periods)')
    p.add_argument('--rate', type=float, default=512.0,
                   help='loop rate [Hz] (512: at 1024 Hz the Python relay, three SCHED_FIFO '
                        'nodes and the recorder overload this 2-core machine; the recorder '
                        'then loses best-effort samples and the identification has gaps)')
    p.add_argument('--duration', type=float, default=20.0,
                   help='simulated seconds of each RTHS run (20)')
    p.add_argument('--ident-duration', type=float, default=30.0,
                   help='seconds of each identification run (30: three 10 s records)')
    p.add_argument('--record', default='kobe', help='ground motion (kobe)')
    p.add_argument('--scale', type=float, default=0.135, help='ground-motion scale (0.135)')
    p.add_argument('--priority', type=int, default=80, help='SCHED_FIFO priority of the bridge')
    p.add_argument('--domain', type=int, default=73, help='ROS domain A (B is A + 1)')
    p.add_argument('--netns', action=argparse_bool(), default=os.geteuid() == 0,
                   help='run each node in its own network namespace (needs root)')
    p.add_argument('--keep', action='store_true', help='keep the bags and logs')
    p.set_defaults(func=cmd_bench_absorb)


def argparse_bool():
    """Return the argparse action of a ``--flag/--no-flag`` option."""
    return argparse.BooleanOptionalAction
