"""``rths install-taps RUN_DIR``: make a run's designed compensator the lab's current taps.

``rths run`` writes the identified plant and the designed taps only into its
results directory (``RUN_DIR/plant.yaml``, ``RUN_DIR/compensator.yaml`` and the
RTHS phase's own params file ``RUN_DIR/rths/config/compensator.yaml``), so a
checkout stays clean.  Installing them into ``config/`` is this explicit step.
"""

from pathlib import Path
import shutil

# Imports of the commands' code sit in the command functions: rths imports this module
# to build its parser, and every rths command would pay for SciPy, matplotlib and ROS.


def register(commands, benches):
    """Add ``rths install-taps``."""
    p = commands.add_parser(
        'install-taps', help="install a run's designed taps (and plant) as config/compensator.yaml",
        description="Copy the compensator that 'rths run' designed (RUN_DIR/compensator.yaml) "
                    'to CONFIG/compensator.yaml and, when the run identified its own plant, '
                    'RUN_DIR/plant.yaml to CONFIG/plant.yaml. rths run never writes into '
                    'config/ itself.')
    p.add_argument('run_dir', help="results directory of 'rths run' (holds compensator.yaml)")
    p.add_argument('--config', default=None, help='config directory (default: repo config/)')
    p.set_defaults(func=cmd_install_taps)


def install_taps(run_dir, config) -> list:
    """Install ``run_dir``'s compensator (and plant) into ``config``; return the files written.

    The installed compensator's ``provenance.plant`` becomes ``plant.yaml`` (beside
    it in ``config``) when the run identified its plant; a run designed from an
    external ``--plant`` keeps its reference to that file.
    """
    from rths_compensator.params import load_compensator_params, write_compensator_params

    run_dir, config = Path(run_dir), Path(config)
    designed = run_dir / 'compensator.yaml'
    if not designed.is_file():
        raise OSError(f'{designed} not found: RUN_DIR must be the results directory of '
                      "'rths run' (it holds compensator.yaml)")
    if not config.is_dir():
        raise OSError(f'config directory {config} does not exist; pass --config DIR')
    params = load_compensator_params(designed)
    written = []
    plant = run_dir / 'plant.yaml'
    if plant.is_file():
        shutil.copyfile(plant, config / 'plant.yaml')
        written.append(config / 'plant.yaml')
        params['provenance']['plant'] = 'plant.yaml'  # relative to the config directory
    fields = ('taps', 'denominator', 'fs_hz', 'scheme')
    write_compensator_params(config / 'compensator.yaml', *(params[f] for f in fields),
                             provenance=params['provenance'])
    written.insert(0, config / 'compensator.yaml')
    return written


def cmd_install_taps(args) -> int:
    """Run ``rths install-taps``."""
    from rths_bringup.commands import default_config_dir

    config = Path(args.config) if args.config else default_config_dir()
    for path in install_taps(args.run_dir, config):
        print(f'wrote {path}')
    return 0
