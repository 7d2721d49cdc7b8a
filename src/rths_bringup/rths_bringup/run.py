"""``rths run``: the whole lab procedure of seed chapter 6 in one command.

1. identification run: the bridge drives the plant (actuator + table + DTM)
   with BLWN (the numerical node plays ``model: excitation``, identity taps),
   recorded to ``OUT/identification/bag``;
2. ARX identification and FIR design (``rths identify`` and ``rths design``:
   WLS, fc = 10 Hz, n = 400 as in seed section 6.1 unless overridden), written to
   ``OUT/plant.yaml`` and ``OUT/compensator.yaml`` and copied to ``CONFIG/compensator.yaml``;
3. the RTHS run: the building (numerical node), the compensator and the bridge
   with the simulated DTM, recorded to ``OUT/rths/bag``;
4. the review (:mod:`rths_bringup.review`): tables 5-9 as text, ``OUT/summary.json``
   and PNG plots.

Every phase writes the exact params files it ran with under ``OUT/<phase>/config``.
"""

import datetime
from pathlib import Path
import shutil
import sys

from rths_bringup import runinfo
from rths_bringup.commands import default_config_dir, launch

NODE_FILES = {'numerical': 'numerical.yaml', 'compensator': 'compensator.yaml',
              'bridge': 'bridge.yaml'}


def register(commands, benches):
    """Add ``rths run`` and ``rths review``."""
    p = commands.add_parser(
        'run', help='the main job: identify, design, run the RTHS, review (seed chapter 6)',
        description='Perform the whole lab procedure of seed chapter 6: (1) identification run with BLWN, '
        '(2) ARX identification and FIR design written to CONFIG/compensator.yaml, (3) the '
        'RTHS of the 2-story building with the simulated DTM, (4) the review: actuator delay '
        'and tracking error before/after compensation (table 5), 2nd-floor response and '
        'reductions vs the uncontrolled building (tables 6-8), RTHS vs whole-numerical '
        'reference (table 9), written to OUT/summary.json, OUT/review.txt and PNG plots.')
    p.add_argument('--config', default=None, help='config directory (default: repo config/)')
    p.add_argument('--out', default=None, help='results directory (default: out/run-<time>)')
    p.add_argument('--record', default='kobe',
                   help='ground motion: kobe, northridge, imperial_valley or a PEER .AT2 path '
                        '(default kobe)')
    p.add_argument('--scale', type=float, default=0.135,
                   help='ground-motion scale factor (seed: kobe 0.135, northridge 0.039, '
                        'el centro 0.10; default 0.135)')
    p.add_argument('--damper', default='valve4',
                   help='DTM configuration of Table 4: valve1..valve4, novalve (default valve4)')
    p.add_argument('--mode', choices=('lockstep', 'realtime'), default='lockstep',
                   help='timing mode (default lockstep: deterministic, as fast as possible)')
    p.add_argument('--duration', type=float, default=0.0,
                   help='simulated seconds of the RTHS run (default 0: the whole record)')
    p.add_argument('--scheme', default='wls', help='compensator scheme (default wls)')
    p.add_argument('--fc', type=float, default=10.0, help='FIR cut-off [Hz] (default 10)')
    p.add_argument('--taps', type=int, default=400, help='FIR taps n (default 400)')
    p.add_argument('--ident-duration', type=float, default=40.0,
                   help='identification run length [s] (default 40: 4 records of 10 s)')
    p.add_argument('--plant', default=None,
                   help='skip steps 1-2 and design from this identified plant.yaml')
    p.add_argument('--no-compensation', action='store_true',
                   help='skip steps 1-2 and run with identity taps (shows the uncompensated '
                        'error and, where the loop goes unstable, the safe abort)')
    p.set_defaults(func=cmd_run)

    p = commands.add_parser(
        'review', help='rebuild the review (tables 5-9, plots, summary.json) from an RTHS bag',
        description='Rebuild the step-4 report of rths run from a recorded RTHS bag alone: '
                    'the run parameters are read from the bag run information, the reference '
                    'and uncontrolled simulations are recomputed.')
    p.add_argument('bag', help='bag directory of an RTHS run')
    p.add_argument('--out', default=None, help='directory for summary.json, review.txt and '
                   'plots (default: beside the bag)')
    p.set_defaults(func=cmd_review)


def _say(text):
    print(f'[run] {text}', flush=True)


def _phase_config(out_dir: Path, sections: dict) -> Path:
    """Write the three params files of one phase (``sections``: node -> params); return the dir."""
    cfg = out_dir / 'config'
    for node, fname in NODE_FILES.items():
        runinfo.write_params(cfg / fname, node, sections[node])
    return cfg


def _launch_phase(name, cfg, bag, kind, fs, mode, sections, history=None):
    overrides = {'recorder': runinfo.flatten(kind, fs, mode, sections)}
    if history:
        overrides['numerical'] = {'history_out': str(Path(history).resolve())}
    for node in NODE_FILES:
        overrides.setdefault(node, {})['mode'] = mode
    _say(f'{name}: launching the node graph ({mode}), recording to {bag}')
    code = launch(cfg, bag=bag, overrides=overrides, timeout=3600.0)
    if code != 0:
        raise RuntimeError(f'{name} run failed (launcher exit {code}); see the log above '
                           f'and the bag {bag}')


def _install_compensator(designed: Path, target: Path, external_plant: bool):
    """Copy the designed compensator into the config dir; its plant becomes config/plant.yaml."""
    from rths_compensator.params import load_compensator_params, write_compensator_params

    params = load_compensator_params(designed)
    if not external_plant:
        params['plant'] = 'plant.yaml'  # relative to the config directory, copied beside it
    fields = ('taps', 'denominator', 'fs_hz', 'scheme')
    write_compensator_params(target, *(params[f] for f in fields),
                             provenance={k: v for k, v in params.items() if k not in fields})


def cmd_run(args) -> int:
    try:
        return _run(args)
    except RuntimeError as err:
        print(f'rths run: error: {err}', file=sys.stderr)
        return 1


def _run(args) -> int:
    from rths_bringup.cli import main as rths_main
    from rths_bringup.review import review_rths, print_review

    config = Path(args.config) if args.config else default_config_dir()
    out = Path(args.out) if args.out else Path('out') / (
        'run-' + datetime.datetime.now().strftime('%Y%m%d-%H%M%S'))
    if out.exists() and any(out.iterdir()):
        raise OSError(f'results directory {out} exists and is not empty; choose a new --out')
    out.mkdir(parents=True, exist_ok=True)
    base = {node: runinfo.load_params(config / fname, node) for node, fname in NODE_FILES.items()}
    fs = float(base['numerical'].get('fs_hz', 1024.0))
    base['bridge']['fs_hz'] = fs
    base['bridge']['dtm'] = args.damper
    _say(f'results in {out}')

    # 1-2: identification and design
    comp_file = out / 'compensator.yaml'
    if args.no_compensation:
        runinfo.write_params(comp_file, 'compensator',
                             {'scheme': 'identity', 'fs_hz': fs, 'taps': [1.0],
                              'denominator': [1.0]})
        _say('no compensation: identity taps')
    else:
        plant = Path(args.plant) if args.plant else out / 'plant.yaml'
        if not args.plant:
            ident = out / 'identification'
            numerical = {'mode': args.mode, 'executor': base['numerical'].get('executor',
                                                                              'events'),
                         'model': 'excitation', 'fs_hz': fs,
                         'duration_s': float(args.ident_duration),
                         'excitation_band_hz': 64.0, 'excitation_peak_m': 0.00254, 'seed': 7}
            # the excitation replaces the building: only its own keys apply
            cfg = _phase_config(ident, {
                'numerical': numerical, 'bridge': base['bridge'],
                'compensator': dict(base['compensator'], scheme='identity', taps=[1.0],
                                    denominator=[1.0], fs_hz=fs)})
            _launch_phase('identification', cfg, ident / 'bag', 'identification', fs, args.mode,
                          {'numerical': numerical, 'bridge': base['bridge']})
            _say('step 2: ARX identification (rths identify)')
            code = rths_main(['identify', '--bag', str(ident / 'bag'), '--out', str(plant)])
            if code:
                raise RuntimeError('identification failed')
            shutil.copyfile(plant, config / 'plant.yaml')
        _say(f'step 2: design {args.scheme} n={args.taps} fc={args.fc} Hz (rths design)')
        code = rths_main(['design', '--plant', str(plant), '--scheme', args.scheme,
                          '--taps', str(args.taps), '--fc', str(args.fc),
                          '--out', str(comp_file)])
        if code:
            raise RuntimeError('compensator design failed')
        _install_compensator(comp_file, config / 'compensator.yaml', bool(args.plant))
        _say(f'compensator written to {config / "compensator.yaml"}'
             + ('' if args.plant else f' (its plant: {config / "plant.yaml"})'))
    comp = runinfo.load_params(comp_file, 'compensator')
    comp.update({k: base['compensator'][k] for k in ('executor',) if k in base['compensator']})

    # 3: the RTHS run
    numerical = dict(base['numerical'], model='building2story', record=args.record,
                     scale=float(args.scale), force_scale=5.0, interface_frame='absolute')
    for key in ('sdof_mass_kg', 'sdof_freq_hz', 'sdof_zeta', 'harmonic_freq_hz'):
        numerical.pop(key, None)
    numerical['duration_s'] = float(args.duration)
    rths_dir = out / 'rths'
    cfg = _phase_config(rths_dir, {'numerical': numerical, 'compensator': comp,
                                   'bridge': base['bridge']})
    _launch_phase('RTHS', cfg, rths_dir / 'bag', 'rths', fs, args.mode,
                  {'numerical': numerical, 'bridge': base['bridge'],
                   'compensator': {k: v for k, v in comp.items() if k in (
                       'scheme', 'n_taps', 'fc_hz', 'plant', 'predicted_delay_ms')}},
                  history=rths_dir / 'numerical_history.npz')

    # 4: review
    _say('step 4: review')
    summary = review_rths(rths_dir / 'bag', out)
    print_review(summary)
    _say(f'results: {out}/summary.json, {out}/review.txt, plots {out}/*.png, '
         f'bags {out}/*/bag')
    return 0


def cmd_review(args) -> int:
    from rths_bringup.review import review_rths, print_review

    bag = Path(args.bag)
    out = Path(args.out) if args.out else bag.parent
    summary = review_rths(bag, out)
    print_review(summary)
    print(f'wrote {out}/summary.json, {out}/review.txt and plots')
    return 0

