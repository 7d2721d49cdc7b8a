"""The orchestration sub-commands of ``rths``: launch and bag."""

import json
import os
from pathlib import Path

# Imports of the commands' code sit in the command functions: rths imports this module
# to build its parser, and every rths command would pay for SciPy, matplotlib and ROS.


def register(commands, benches):
    """Add ``rths launch`` and ``rths bag info|reindex|repair|verify|export``."""
    p = commands.add_parser(
        'launch', help='start the node graph (composed or one process per node), supervise it',
        description='Start the actuator bridge, compensator and numerical node, each with its '
                    'params file from --config: composed in one process on one executor '
                    '(--layout composed, the default in realtime mode) or as separate processes '
                    '(--layout processes, as ros2 run would; the default in lock-step); stream '
                    'their logs prefixed with the node name; record every loop topic to --bag '
                    '(composed: through a pipe from the container, nothing lost). Ends when the '
                    'numerical node finishes the run, on Ctrl-C/SIGTERM, or when a node dies '
                    '(exit code 1, naming the node).')
    add_launch_args(p)
    p.add_argument('--enclave-keystore', default=None, metavar='DIR',
                   help='start every process of the run inside its SROS2 enclave /rths/NAME '
                        'of this keystore (DDS authentication and encryption; needs a ROS 2 '
                        'install with DDS security, not the wheels: docs/lab_network.md)')
    from rths_live import live
    live.add_arguments(p)
    p.set_defaults(func=cmd_launch)

    bag = commands.add_parser('bag', help='inspect or repair a recorded bag',
                              description='Inspect or repair a rosbag2 bag recorded by rths.')
    bag_cmds = bag.add_subparsers(dest='bag_command', metavar='ACTION')
    bag_cmds.required = True
    b = bag_cmds.add_parser('info', help='print topics, message counts and duration',
                            description='Print the topics, types, message counts, start time '
                                        'and duration of a bag (reindexing it first if a crash '
                                        'left it without metadata.yaml).')
    b.add_argument('bag', help='bag directory')
    b.add_argument('--json', action='store_true', help='print JSON instead of a table')
    b.set_defaults(func=cmd_bag_info)
    b = bag_cmds.add_parser('reindex', help='rebuild metadata.yaml of a crashed recording',
                            description='Rebuild metadata.yaml from the bag data file, MCAP '
                                        'or sqlite3 (like ros2 bag reindex); an MCAP file a '
                                        'killed recorder left without its footer is closed '
                                        'after its last complete record first.')
    b.add_argument('bag', help='bag directory')
    b.set_defaults(func=cmd_bag_reindex)
    b = bag_cmds.add_parser('repair', help='recover a killed recording up to its last complete '
                                           'chunk',
                            description='Recover the bag of a recording whose writer was '
                                        'killed (SIGKILL, power loss): the MCAP file is cut '
                                        'after its last complete chunk and closed, sqlite3 '
                                        'rolls back its open transaction, and metadata.yaml '
                                        'is rebuilt; then print what the bag holds. The '
                                        'recorder commits every 0.05 s, so at most the last '
                                        '0.1 s before the kill is lost. A whole bag is left '
                                        'untouched.')
    b.add_argument('bag', help='bag directory')
    b.set_defaults(func=cmd_bag_repair)
    b = bag_cmds.add_parser('verify', help='check a bag is whole and complete (exit 1 if not)',
                            description='Check a bag as the evidence of a run, without changing '
                                        'it: integrity (MCAP: the CRC-32 of every chunk; '
                                        'sqlite3: PRAGMA integrity_check), completeness (every '
                                        'bridge tick has its measurement and status; commands '
                                        'and interface displacements aligned as the review '
                                        'does: re-sends and short gaps counted, longer gaps '
                                        'fail) and provenance (rths version, git commit, host, '
                                        'the params and plant files). Exit 0 when the bag is '
                                        'whole and complete, 1 when it is damaged, cut or '
                                        'incomplete (each problem on one line).')
    b.add_argument('bag', help='bag directory')
    b.add_argument('--json', action='store_true', help='print the report as JSON')
    b.set_defaults(func=cmd_bag_verify)
    b = bag_cmds.add_parser('export', help='write the restoring-force CSV of a run bag',
                            description='Write the measured displacement and force of an rths '
                                        'run bag (channel 0) as a CSV of the restoring-force '
                                        'contract: time_s, displacement_m, force_N; read it '
                                        'with rths discrepancy --scenario restoring-force '
                                        '--measured F.csv (or pass the bag itself).')
    b.add_argument('bag', help='bag directory (e.g. RUN_DIR/rths/bag)')
    b.add_argument('--out', required=True, help='CSV file to write')
    b.set_defaults(func=cmd_bag_export)


def cmd_bag_export(args) -> int:
    """``rths bag export BAG --out F.csv``: the restoring-force columns of a run bag."""
    from rths_discrepancy import restoring

    data = restoring.validate(restoring.read_bag(args.bag), source=args.bag)
    restoring.write_csv(args.out, data)
    print(f"wrote {args.out}: {data['time_s'].size} rows at {data['fs']:g} Hz "
          f"({', '.join(restoring.COLUMNS)})")
    return 0


def add_launch_args(p):
    """Arguments shared by launch-like commands."""
    p.add_argument('--config', default=None,
                   help='directory with bridge.yaml, compensator.yaml, numerical.yaml '
                        '(default: the repo config/)')
    p.add_argument('--duration', type=float, default=None,
                   help='simulated duration of the run [s] (overrides numerical duration_s)')
    p.add_argument('--bag', default=None, help='record every loop topic to this new bag directory')
    p.add_argument('--layout', choices=('composed', 'processes'), default=None,
                   help='composed: the three nodes in one process on one executor (the bridge '
                        'is its clock); processes: one process per node. Default: composed in '
                        'realtime mode, processes in lock-step')
    p.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap',
                   help='bag storage (default mcap, as ros2 bag since Iron; sqlite3 for older '
                        'tools)')
    p.add_argument('--mode', choices=('lockstep', 'realtime'), default=None,
                   help='timing mode of every node (default: the mode the params files give, '
                        'which must agree; mixed modes are refused before anything starts)')
    p.add_argument('--timeout', type=float, default=600.0,
                   help='wall-clock limit [s] after which the run is stopped as failed '
                        '(default 600)')


def default_config_dir() -> Path:
    """Return the repo's config/ (RTHS_ROOT is set by env.sh), else ./config."""
    root = os.environ.get('RTHS_ROOT')
    return Path(root) / 'config' if root else Path('config')


def run_info_of(config, overrides) -> dict:
    """Return the recorder's run information for a run of ``config`` with ``overrides`` applied."""
    from rths_common import runinfo

    sections = {node: dict(runinfo.load_params(Path(config) / f'{node}.yaml', node),
                           **overrides.get(node, {}))
                for node in ('numerical', 'compensator', 'bridge')}
    numerical = sections['numerical']
    kind = 'identification' if numerical.get('model') == 'excitation' else 'rths'
    return runinfo.flatten(kind, numerical.get('fs_hz', 1024.0),
                           numerical.get('mode', 'lockstep'), sections)


def launch(config, duration=None, bag=None, timeout=600.0, overrides=None, storage=None,
           live=False, layout=None, progress_label='run', mode=None, enclave_keystore=None):
    """Run the graph; return the launcher's exit code.

    With a bag, the run's parameters (the three params files with the
    overrides applied) go into the bag's run information, so ``rths review``,
    ``rths identify --bag`` and ``rths discrepancy`` need nothing but the bag.
    """
    from rths_bringup.launcher import Launcher
    from rths_bringup.security import enclave_env

    # checked before anything starts: a missing keystore or enclave is one line
    node_env = enclave_env(enclave_keystore) if enclave_keystore else None
    config = Path(config) if config else default_config_dir()
    overrides = overrides or {}
    if mode is not None:            # one switch for every node (the recorder's QoS follows)
        for node in ('numerical', 'compensator', 'bridge'):
            overrides.setdefault(node, {})['mode'] = mode
    if duration is not None:
        if not duration > 0:
            raise ValueError(f'--duration must be > 0 s, got {duration}')
        overrides.setdefault('numerical', {})['duration_s'] = float(duration)
    if bag and 'kind' not in overrides.get('recorder', {}):
        overrides['recorder'] = dict(run_info_of(config, overrides),
                                     **overrides.get('recorder', {}))
    if bag and storage:
        overrides.setdefault('recorder', {})['storage'] = storage
    launcher = Launcher(config, bag=bag, overrides=overrides, timeout_s=timeout, layout=layout,
                        progress_label=progress_label, node_env=node_env)
    if live:  # the live view is one more reader of each loop topic: arm the chain after it too
        # (composed, the recorder reads the container's pipe, not the topics)
        readers = 3 if bag and launcher.layout == 'processes' else 2
        for name in ('numerical', 'compensator', 'bridge'):
            launcher.overrides.setdefault(name, {}).setdefault('wait_for_subscribers', readers)
    return launcher.run()


def cmd_launch(args) -> int:
    """Run ``rths launch``; then print the bag's topics and the loop summary."""
    from rths_bringup.security import enclave_env
    from rths_live import live

    if args.enclave_keystore:
        enclave_env(args.enclave_keystore)   # refused before the live view starts too
    fs = live_rate_of(args.config) if args.live else 0.0
    with live.session(args, fs_hz=fs):
        code = launch(args.config, args.duration, args.bag, args.timeout, storage=args.storage,
                      live=args.live, layout=args.layout, mode=getattr(args, 'mode', None),
                      enclave_keystore=args.enclave_keystore)
    if args.bag and Path(args.bag).exists():
        from rths_review.evidence import bag_missing
        from rths_review.review import loop_summary
        print_bag_info(args.bag)
        summary = loop_summary(args.bag)
        missing = bag_missing(summary)
        summary['bag_complete'] = not missing
        print_summary(summary)
        for text in missing:
            print(f'BAG INCOMPLETE: {text}')
    return code


def live_rate_of(config) -> float:
    """Return the loop rate ``fs_hz`` of a config directory's numerical node (1024 if unset)."""
    from rths_common import runinfo

    config = Path(config) if config else default_config_dir()
    return float(runinfo.load_params(config / 'numerical.yaml', 'numerical').get('fs_hz', 1024.0))


def print_bag_info(bag, as_json=False):
    """Print a bag's topics and counts."""
    from rths_common.bagio import info

    data = info(bag)
    if as_json:
        print(json.dumps(data, indent=2))
        return data
    print(f"bag: {data['path']} ({data['storage']})")
    print(f"duration: {data['duration_s']:.3f} s   messages: {data['message_count']}")
    print(f"{'topic':<32} {'type':<40} {'count':>8}")
    for topic, t in data['topics'].items():
        print(f"{topic:<32} {t['type']:<40} {t['count']:>8}")
    if data['damaged']:
        print(f"BAG DAMAGED: {data['damaged']}; the counts are of the readable messages")
    return data


def cmd_bag_info(args) -> int:
    """``rths bag info``."""
    print_bag_info(args.bag, args.json)
    return 0


def cmd_bag_reindex(args) -> int:
    """``rths bag reindex``."""
    from rths_common.bagio import reindex
    print(f'wrote {reindex(args.bag)}')
    return 0


def cmd_bag_repair(args) -> int:
    """``rths bag repair``."""
    from rths_review.evidence import repair

    result = repair(args.bag)
    if not result['repaired']:
        print(f'{args.bag}: closed and indexed; nothing to repair')
    else:
        print(f"{args.bag}: recovered up to the last complete chunk; metadata.yaml rebuilt")
    for topic, count in result['topics'].items():
        print(f'  {topic}: {count} messages')
    if result['last_step'] is not None:
        print(f"  last bridge tick recorded: step {result['last_step']}")
    return 0


def cmd_bag_verify(args) -> int:
    """``rths bag verify``: 0 whole and complete, 1 damaged, cut or incomplete."""
    from rths_review.evidence import print_report, verify

    report = verify(args.bag)
    if args.json:
        print(json.dumps(report, indent=2))
    else:
        print_report(report)
    return 1 if report['problems'] else 0


def print_summary(summary: dict):
    """Print the run summary of :func:`rths_review.review.loop_summary`."""
    print('\nrun summary')
    for key, value in summary.items():
        if isinstance(value, dict):
            print(f'  {key}:')
            for k, v in value.items():
                print(f'    {k}: {v}')
        else:
            print(f'  {key}: {value}')
