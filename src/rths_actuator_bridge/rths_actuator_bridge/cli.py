"""Sub-commands this package adds to the ``rths`` command (see rths_bringup.cli).

``rths controller-emulator``  the reference servo controller (simulated plant, faults)
``rths controller-check``     conformance check of a servo controller (docs/controller_protocol.md)
``rths site``                 an OpenFresco-compatible experimental site (genericClient protocol)
``rths characterise-dtm``     identify c_d, k_d, zeta, f_n of the DTM from shake-table tests
``rths bench dtm``            reproduce Table 4 from simulated tests of the five configurations
"""

import argparse
import json
import sys
import time

from rths_common.files import atomic_open
from rths_common.params import add_renamed_option
from rths_numerical.specimens import DEFAULT_SPECIMEN, SPECIMENS

# Imports of the commands' code sit in the command functions: rths imports this module
# to build its parser, and every rths command would pay for SciPy, matplotlib and ROS.


def _progress(text: str):
    print(text, file=sys.stderr, flush=True)


def _write_json(path, data):
    """Atomic JSON write (temp file + rename)."""
    with atomic_open(path) as fh:
        json.dump(data, fh, indent=2)


def _add_plant_options(p):
    p.add_argument('--actuator-model', default='3pole',
                   help="'3pole' | '4pole' (Table 1) or a plant.yaml (default 3pole)")
    p.add_argument('--specimen', default=DEFAULT_SPECIMEN, choices=SPECIMENS.names(),
                   help=f'the specimen on the table (default {DEFAULT_SPECIMEN})')
    add_renamed_option(p, '--dtm', '--specimen')
    p.add_argument('--fs-hz', type=float, default=1024.0, help='sampling frequency [Hz]')
    p.add_argument('--seed', type=int, default=0, help='noise generator seed')
    p.add_argument('--displacement-noise-m', type=float, default=0.0,
                   help='std of displacement noise [m]')
    p.add_argument('--force-noise-n', type=float, default=0.0, help='std of force noise [N]')
    p.add_argument('--adc-bits', type=int, default=0, help='ADC bits (0 = no quantisation)')
    p.add_argument('--friction-n', type=float, default=0.0,
                   help='Coulomb friction on the DTM moving mass [N]')


def run_emulator(args) -> int:
    """Serve the simulated plant over UDP until interrupted or --duration-s elapses."""
    from .emulator import ControllerEmulator
    params = {'actuator_model': args.actuator_model, 'specimen': args.specimen,
              'fs_hz': args.fs_hz,
              'seed': args.seed, 'displacement_noise_m': args.displacement_noise_m,
              'force_noise_n': args.force_noise_n, 'adc_bits': args.adc_bits,
              'friction_n': args.friction_n}
    if not 0 <= args.port <= 65535:
        raise ValueError(f'--port {args.port} must be 0 (any free port) .. 65535')
    faults = {}
    for flag in ('drop_every', 'late_every', 'malformed_at', 'silence_at', 'restart_at'):
        value = getattr(args, flag)
        if value is not None:
            if value < (1 if flag.endswith('every') else 0):
                raise ValueError(f"--{flag.replace('_', '-')} {value} must be >= "
                                 f"{1 if flag.endswith('every') else 0}")
            faults[flag] = value
    for flag in ('late_ms', 'silence_ms', 'restart_ms'):
        value = getattr(args, flag)
        if not (value > 0 and value < 60_000):
            raise ValueError(f"--{flag.replace('_', '-')} {value} must lie in (0, 60000) ms")
        faults[flag.replace('_ms', '_s')] = value * 1e-3
    emu = ControllerEmulator(params, host=args.host, port=args.port, faults=faults,
                             n_channels=args.channels, stroke_m=args.stroke_m,
                             velocity_m_s=args.velocity_m_s, wall_clock=args.wall_clock,
                             interlock_s=args.interlock_s, rt_priority=args.rt_priority)
    host, port = emu.address
    active = ', '.join(f'{k} {v:g}' for k, v in faults.items()
                       if k in ('drop_every', 'late_every', 'malformed_at', 'silence_at',
                                'restart_at'))
    print(f'controller emulator listening on {host}:{port} (UDP, protocol versions 1 and 2, '
          f'{args.channels} channel(s), plant {args.actuator_model} + specimen {args.specimen}, '
          f'{"wall clock" if args.wall_clock else "lock-step"}'
          f'{", faults: " + active if active else ""})', flush=True)
    emu.start()
    try:
        t_end = time.monotonic() + args.duration_s if args.duration_s > 0 else float('inf')
        while time.monotonic() < t_end:
            time.sleep(0.05)
    except KeyboardInterrupt:
        pass
    finally:
        emu.stop()
        print(f'controller emulator stopped: {emu.stats}', flush=True)
    return 0


def run_check(args) -> int:
    """Check a servo controller's conformance; print and (--out) save the report."""
    from .check import check_controller, report_text, rig_channels
    host, sep, port = args.address.rpartition(':')
    if not sep or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ValueError(f'{args.address!r}: give the controller as HOST:PORT '
                         '(e.g. 192.168.1.20:5005)')
    channels, actuators = rig_channels(args.rig_file, args.channels, args.amplitude_m)
    if actuators:
        _progress(f'rig file {args.rig_file}: {channels} channels (actuators '
                  f'{", ".join(actuators)})')
    report = check_controller(host or '127.0.0.1', int(port), channels=channels,
                              fs_hz=args.fs_hz, steps=args.steps, version=args.version,
                              amplitude_m=args.amplitude_m, timeout_s=args.timeout_s,
                              late_tolerance=args.late_tolerance_pct / 100,
                              rt_priority=args.rt_priority, progress=_progress)
    if actuators:
        report.update(rig_file=args.rig_file, actuators=actuators)
    print(report_text(report), end='', flush=True)
    if args.out:
        _write_json(args.out, report)
        print(f'wrote {args.out}')
    return 0 if report['passed'] else 1


def run_characterise(args) -> int:
    """Fit eq. 47 to the given records; print the parameters; optional JSON and plot."""
    from .characterise import MOVING_MASS_KG, fit_dtm, plot_fit, read_bag, read_csv
    records = [read_csv(p) for p in (args.csv or [])] + [read_bag(p) for p in (args.bag or [])]
    if not records:
        raise ValueError('give at least one record with --csv FILE or --bag BAG')
    m_d = args.mass_kg if args.mass_kg is not None else MOVING_MASS_KG
    if args.band_hz is not None:
        for r in records:
            r.band_hz = (0.0, args.band_hz)
    _progress(f'fitting eq. 47 to {len(records)} record(s), m_d = {m_d:.5g} kg ...')
    fit = fit_dtm(records, m_d=m_d)
    result = {'combined': fit.as_dict()}
    print(f'c_d = {fit.c_d:.6g} N s/m, k_d = {fit.k_d:.6g} N/m, zeta = {100 * fit.zeta:.4g} %, '
          f'f_n = {fit.f_n:.4g} Hz (fit {fit.fit_pct:.2f} %, {fit.n_records} record(s))')
    if len(records) > 1:
        result['per_record'] = []
        for r in records:
            f = fit_dtm(r, m_d=m_d, initial=(fit.c_d, fit.k_d))
            result['per_record'].append(dict(f.as_dict(), name=r.name))
            print(f'  {r.name}: zeta = {100 * f.zeta:.4g} %, f_n = {f.f_n:.4g} Hz')
    if args.plot:
        plot_fit(records, fit, args.plot)
        print(f'wrote {args.plot}')
    if args.out:
        _write_json(args.out, result)
        print(f'wrote {args.out}')
    return 0


def run_bench_dtm(args) -> int:
    """Simulate the seed's tests for each configuration, identify, compare with Table 4."""
    from rths_common.progress import Progress
    from rths_numerical.dtm import TABLE4

    from .characterise import bench_dtm
    configs = args.configs.split(',') if args.configs else None
    with Progress(len(configs or TABLE4), 'bench dtm', 'configurations') as bar:
        def done(text):
            bar.write(text)
            bar.advance()
        result = bench_dtm(configs, blwn_s=args.blwn_s, chirp_s=args.chirp_s, progress=done,
                           plot_dir=args.plots)
    flat = {name: {k: e[k] for k in ('c_d', 'k_d', 'zeta', 'f_n')}
            for name, e in result['configurations'].items()}
    out = dict(flat)
    out['details'] = result
    for name, e in result['configurations'].items():
        pr = e.get('per_record', {})
        line = (f'{name:8s} c_d {e["c_d"]:9.4g} k_d {e["k_d"]:9.6g} zeta {100 * e["zeta"]:6.3f} % '
                f'f_n {e["f_n"]:6.4f} Hz  worst error {max(e["error_pct"].values()):.2f} %')
        if pr:
            zb, zc = pr['blwn']['zeta_pct'], pr['chirp']['zeta_pct']
            line += (f'  BLWN zeta {zb["mean"]:.3f}+-{zb["std"]:.3f} %, '
                     f'chirp zeta {zc["mean"]:.3f}+-{zc["std"]:.3f} %')
        print(line)
    print(f'worst error vs Table 4: {result["worst_error_pct"]:.3f} % '
          f'({"within" if result["all_within_tolerance"] else "NOT within"} 3 %)')
    _write_json(args.out, out)
    print(f'wrote {args.out}')
    return 0


def run_site(args) -> int:
    """``rths site``: serve one OpenSees/OpenFresco client session, record it, exit."""
    import datetime
    import os
    from pathlib import Path
    import signal

    from .site import load_site_config
    from .site_server import check_allow, listen, run, server_tls_context

    if not 0 <= args.port <= 65535:
        raise ValueError(f'--port {args.port} must be 0 (any free port) .. 65535')
    root = os.environ.get('RTHS_ROOT')
    config = load_site_config(args.config, Path(root) / 'config' if root else None)
    site = config['site']
    if args.allow:
        site['allow'] = args.allow
    site['allow'] = check_allow(site['allow'])
    if args.mode:
        site['mode'] = args.mode
    tls = None
    if args.tls_cert or args.tls_key or args.tls_ca:
        tls = server_tls_context(args.tls_cert, args.tls_key, args.tls_ca)
    stamp = datetime.datetime.now().strftime('%Y%m%d-%H%M%S')
    bag = Path(args.bag) if args.bag else Path('out') / f'site-{stamp}' / 'bag'
    listener = listen(args.host, args.port)
    signal.signal(signal.SIGTERM, signal.default_int_handler)   # SIGTERM stops safely too
    if args.rt_priority:
        realtime_priority(args.rt_priority)
    try:
        summary = run(config, listener, bag, tls, args.wait_s or None)
    finally:
        listener.close()
    if args.summary:
        _write_json(args.summary, summary)
    return summary['exit_code']


def realtime_priority(priority: int) -> bool:
    """Run this process SCHED_FIFO at ``priority`` (1..99); say so, or why not."""
    import gc
    import os

    from .site_server import log
    gc.freeze()   # what exists now is never scanned again: shorter collections in the session
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(int(priority)))
    except (OSError, ValueError) as err:
        log(f'SCHED_FIFO {priority} refused ({err}): normal priority (give the process '
            'CAP_SYS_NICE or run it as root for tighter timing)')
        return False
    log(f'SCHED_FIFO priority {priority}')
    return True


def _add_site_parser(commands):
    p = commands.add_parser(
        'site', help='be an OpenFresco-compatible experimental site for OpenSees genericClient',
        description='Serve one OpenSees genericClient (or OpenFresco) client over TCP: the '
                    "client's trial displacement goes through the compensator and the actuator "
                    "bridge (any backend, under the safety supervisor); the load cell's force "
                    'goes back. Pseudo-dynamic (each new trial is one loop step) or realtime '
                    "(the site's own loop at fs_hz). Every loop step is recorded to --bag "
                    '(rths review reads it). A bad peer (truncated, wrong size, non-finite, '
                    'unknown action, vanished, a second client) stops the actuator safely. '
                    'Ends when the client says goodbye (docs/openfresco.md).',
        epilog='Exit codes: 0 the client said goodbye; 3 safety stop (bad peer or a fault of '
               'the supervisor); 2 bad input.')
    p.add_argument('--port', type=int, required=True,
                   help='TCP port to listen on (the genericClient -server port; 0 = any free)')
    p.add_argument('--host', default='127.0.0.1',
                   help='address to bind (default 127.0.0.1: this machine only; 0.0.0.0 for a '
                        'lab network, with --allow)')
    p.add_argument('--config', default=None,
                   help='site config YAML: site: (mode, matrices, client_timeout_s, allow), '
                        'bridge: and compensator: (params files or inline; default the repo '
                        "config/'s bridge.yaml and compensator.yaml)")
    p.add_argument('--mode', choices=('pseudodynamic', 'realtime'), default=None,
                   help='override the config: pseudodynamic (default) or realtime')
    p.add_argument('--bag', default=None,
                   help='new bag directory for the run (default out/site-<time>/bag)')
    p.add_argument('--allow', action='append', metavar='ADDR',
                   help='client address or network allowed (repeatable; default the '
                        "config's allow, else 127.0.0.1 and ::1)")
    p.add_argument('--tls-cert', default='', help='site certificate (PEM): TLS on')
    p.add_argument('--tls-key', default='', help='private key of --tls-cert (PEM)')
    p.add_argument('--tls-ca', default='',
                   help='CA (PEM) that must have signed the client certificate: mutual TLS')
    p.add_argument('--rt-priority', type=int, default=0, choices=range(0, 100),
                   metavar='0..99',
                   help='SCHED_FIFO priority of the site process (0 = normal scheduling, the '
                        'default); on a loaded machine it keeps the round trip short')
    p.add_argument('--summary', default=None, metavar='FILE.json',
                   help='write the session summary (steps, commits, messages, safety_state, '
                        'fault, exit_code, bag) here at the end')
    p.add_argument('--wait-s', type=float, default=0.0,
                   help='give up if no client connects within this many seconds (0 = wait)')
    p.set_defaults(func=run_site)


def register(commands, benches):
    """Add this package's ``rths <command>`` and ``rths bench <name>`` parsers."""
    _add_site_parser(commands)
    p = commands.add_parser(
        'controller-emulator', help='run the simulated plant behind the UDP servo protocol',
        description='Emulate the servo controller: answer the bridge\'s UDP COMMAND datagrams '
                    'with the simulated actuator + shake table + DTM (lock-step, one sample per '
                    'command). Prints the address it listens on, then serves until Ctrl-C or '
                    '--duration-s.')
    p.add_argument('--host', default='127.0.0.1', help='address to bind (default 127.0.0.1)')
    p.add_argument('--port', type=int, default=0, help='UDP port (0 = any free port)')
    p.add_argument('--duration-s', type=float, default=0.0,
                   help='stop after this many seconds (0 = run until Ctrl-C)')
    p.add_argument('--channels', type=int, default=1,
                   help='actuators (each its own simulated plant; default 1)')
    p.add_argument('--stroke-m', type=float, default=0.254,
                   help="the controller's own stroke limit +- [m] (default 0.254)")
    p.add_argument('--velocity-m-s', type=float, default=2.0,
                   help="the controller's own velocity limit [m/s] (default 2)")
    p.add_argument('--wall-clock', action='store_true',
                   help='run the plant on its own clock at --fs-hz (a late bridge: samples '
                        'hold the last command) with an interlock: no COMMAND for '
                        '--interlock-s brings the actuator to rest (default: lock-step, one '
                        'sample per COMMAND)')
    p.add_argument('--interlock-s', type=float, default=0.1,
                   help='--wall-clock: the interlock time [s] (default 0.1)')
    p.add_argument('--rt-priority', type=int, default=0,
                   help='SCHED_FIFO priority of the serving thread, as a real-time '
                        'controller runs (default 0: normal scheduling)')
    g = p.add_argument_group('faults', 'steps count COMMANDs from ACTIVATE (step 0)')
    g.add_argument('--drop-every', type=int, default=None, metavar='N',
                   help='send no REPLY to steps k > 0 with k %% N == 0')
    g.add_argument('--late-every', type=int, default=None, metavar='N',
                   help='send the REPLY of those steps --late-ms late')
    g.add_argument('--late-ms', type=float, default=2.0, help='delay of a late REPLY [ms]')
    g.add_argument('--malformed-at', type=int, default=None, metavar='K',
                   help='send a malformed datagram instead of the REPLY of step K')
    g.add_argument('--silence-at', type=int, default=None, metavar='K',
                   help='from COMMAND K, read and send nothing for --silence-ms')
    g.add_argument('--silence-ms', type=float, default=300.0, help='silence length [ms]')
    g.add_argument('--restart-at', type=int, default=None, metavar='K',
                   help='restart at COMMAND K: silent for --restart-ms, then inactive with a '
                        'new session')
    g.add_argument('--restart-ms', type=float, default=200.0, help='restart time [ms]')
    _add_plant_options(p)
    p.set_defaults(func=run_emulator)

    p = commands.add_parser(
        'controller-check', help="check a servo controller's conformance to the protocol",
        description='Talk to a servo controller as the bridge would (docs/controller_protocol.md) '
                    'before an actuator is connected: ACTIVATE/ACK (version, channel count, '
                    'reply names), --steps COMMANDs at the loop rate (reply-time distribution; '
                    'lost, late, malformed, duplicate, out-of-order replies with their steps; '
                    'silence; restart), a late and a duplicate COMMAND, HEARTBEAT (version 2), '
                    'DEACTIVATE. The commands hold the position the ACK reports (version 1: '
                    '0 m) plus --amplitude-m. Prints pass/fail per check with figures, naming '
                    'the fault; exit code 0 pass, 1 fail, 2 bad input.')
    p.add_argument('address', metavar='HOST:PORT', help='the controller')
    p.add_argument('--channels', type=int, default=None,
                   help='actuators (default 1, or the rig file\'s)')
    p.add_argument('--rig-file', default='', metavar='RIG.yaml',
                   help='the multi-actuator rig file the bridge gets as rig_file '
                        '(docs/multi_actuator.md): the channels are its actuators, and '
                        '--amplitude-m must stay within each actuator\'s stroke_m')
    p.add_argument('--fs-hz', type=float, default=1024.0, help='loop rate [Hz] (default 1024)')
    p.add_argument('--steps', type=int, default=2048,
                   help='COMMANDs of the sequence (default 2048: 2 s at 1024 Hz)')
    p.add_argument('--version', type=int, choices=(0, 1, 2), default=0,
                   help='protocol version: 0 negotiate (default), 1 or 2')
    p.add_argument('--amplitude-m', type=float, default=0.0,
                   help='a 1 Hz sine of this amplitude [m] on the held position (default 0)')
    p.add_argument('--timeout-s', type=float, default=0.3,
                   help='wait for an ACK or a single reply [s] (default 0.3)')
    p.add_argument('--late-tolerance-pct', type=float, default=0.1,
                   help='scattered late replies tolerated [%% of the steps] (default 0.1; a '
                        'regular pattern of late replies always fails)')
    p.add_argument('--rt-priority', type=int, default=0,
                   help='SCHED_FIFO priority of the checker while it runs (default 0: normal '
                        'scheduling; on a loaded host the checker itself may be late)')
    p.add_argument('--out', metavar='F.json', help='write the report as JSON')
    p.set_defaults(func=run_check)

    p = commands.add_parser(
        'characterise-dtm', help='identify c_d, k_d, zeta, f_n of the DTM from shake-table tests',
        description='Fit the DTM model (seed eq. 47) to BLWN/chirp/sine shake-table records '
                    '(section 5.1.2). CSV columns: time [s], base_accel [m/s^2], rel_disp [m] '
                    '(optional force [N]). Prints c_d, k_d, zeta, f_n; writes the experimental '
                    'vs fitted transfer function (figures 18-21) with --plot and JSON with --out.')
    p.add_argument('--csv', action='append', metavar='FILE', help='record CSV (repeatable)')
    p.add_argument('--bag', action='append', metavar='BAG', help='rosbag2 record (repeatable)')
    p.add_argument('--mass-kg', type=float, default=None,
                   help='moving mass m_d [kg] (default 569.5 lbm = 258.3 kg)')
    p.add_argument('--band-hz', type=float, default=None,
                   help='upper edge of the excitation band [Hz] (default: from the PSD)')
    p.add_argument('--plot', metavar='PNG', help='write the transfer-function plot here')
    p.add_argument('--out', metavar='JSON', help='write the identified parameters here')
    p.set_defaults(func=run_characterise)

    p = benches.add_parser(
        'dtm', help='reproduce Table 4 from simulated DTM tests',
        description='Simulate the seed\'s DTM tests (22 BLWNs, 15 chirps) of valve1..valve4 and '
                    'novalve through the full plant with sensor noise, identify c_d, k_d, zeta, '
                    'f_n, compare with Table 4 (3 %% tolerance) and summarise the per-record '
                    'consistency (figures 22-25). Writes JSON: {config: {c_d, k_d, zeta, f_n}, '
                    '..., details: {...}}.')
    p.add_argument('--out', required=True, metavar='FILE.json', help='JSON result file')
    p.add_argument('--configs', default=None, help='comma-separated subset (default all five)')
    p.add_argument('--blwn-s', type=float, default=60.0, help='BLWN record length [s]')
    p.add_argument('--chirp-s', type=float, default=40.0, help='chirp record length [s]')
    p.add_argument('--plots', metavar='DIR', default=None, help='write dtm_<config>.png here')
    p.set_defaults(func=run_bench_dtm)


def main(argv=None) -> int:
    """Stand-alone ``python -m rths_actuator_bridge.cli ...`` with this package's commands."""
    parser = argparse.ArgumentParser(prog='rths')
    commands = parser.add_subparsers(dest='command', required=True)
    bench = commands.add_parser('bench', help='benchmarks')
    benches = bench.add_subparsers(dest='bench', required=True)
    register(commands, benches)
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ValueError, OSError) as err:
        print(f'rths {args.command}: error: {err}', file=sys.stderr)
        return 2


if __name__ == '__main__':
    sys.exit(main())
