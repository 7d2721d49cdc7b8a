"""Sub-commands this package adds to the ``rths`` command (see rths_bringup.cli).

``rths controller-emulator``  the simulated plant behind the UDP protocol (own process)
``rths characterise-dtm``     identify c_d, k_d, zeta, f_n of the DTM from shake-table tests
``rths bench dtm``            reproduce Table 4 from simulated tests of the five configurations
"""

import argparse
import json
import sys

from rths_common.files import atomic_open
from rths_common.params import add_renamed_option
from rths_numerical.specimens import DEFAULT_SPECIMEN, SPECIMENS


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
    import time

    from .emulator import ControllerEmulator
    params = {'actuator_model': args.actuator_model, 'specimen': args.specimen,
              'fs_hz': args.fs_hz,
              'seed': args.seed, 'displacement_noise_m': args.displacement_noise_m,
              'force_noise_n': args.force_noise_n, 'adc_bits': args.adc_bits,
              'friction_n': args.friction_n}
    if not 0 <= args.port <= 65535:
        raise ValueError(f'--port {args.port} must be 0 (any free port) .. 65535')
    emu = ControllerEmulator(params, host=args.host, port=args.port)
    host, port = emu.address
    print(f'controller emulator listening on {host}:{port} (UDP, plant {args.actuator_model} '
          f'+ specimen {args.specimen})', flush=True)
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


def register(commands, benches):
    """Add this package's ``rths <command>`` and ``rths bench <name>`` parsers."""
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
    _add_plant_options(p)
    p.set_defaults(func=run_emulator)

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
