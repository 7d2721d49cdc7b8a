"""The ``rths`` command: one entry point for every user-facing tool of the project.

Each package contributes its own sub-commands through a module with a
``register(commands, benches)`` function: ``commands`` is the argparse
sub-parser collection of ``rths <command>`` and ``benches`` the one of
``rths bench <name>``.  Every sub-parser sets ``func`` (``func(args) -> int``,
the exit code) with ``set_defaults``.  This package and the ones below it are
listed in :data:`CLI_MODULES`; packages above it (the benchmarks, ``rths_bench``)
declare theirs as ``rths.cli`` entry points in their setup.py, so that nothing
here imports upward.  A module that adds options to another package's command
(``rths_study`` gives ``rths bench rths-benchmark`` its cluster options) does it in
an optional ``extend(commands, benches)``: it runs after every module's
``register``, so it finds the command whatever order the modules load in, and it
raises if the command is missing.

Commands that can run longer than a few seconds (:data:`PROGRESS_COMMANDS` and
every benchmark) show their progress on stderr through
:mod:`rths_common.progress` and take ``--quiet``.

Every int/float option is checked while parsing: a non-finite value, or one
outside its range in :data:`rths_common.params.OPTION_RANGES` (the loop rate's
is :data:`rths_common.params.LOOP_RATE_RANGE_HZ`), is refused with exit code 2
before the command starts.

Errors the user can fix (bad input file, missing column, out-of-range value)
are raised as ``ValueError`` or ``OSError`` with a message that names the
file/field and the fix; they are printed without a traceback and the command
exits with code 2.  Set ``RTHS_DEBUG=1`` to see the traceback.
"""

import argparse
import importlib
from importlib.metadata import entry_points
import os
import sys

# Imports of the commands' code sit in the command functions: rths imports this module
# to build its parser, and every rths command would pay for SciPy, matplotlib and ROS.

#: Modules of this package and the ones below that add sub-commands, in --help order.
CLI_MODULES = (
    'rths_bringup.commands',
    'rths_bringup.run',
    'rths_bringup.install',
    'rths_bringup.replay',
    'rths_bringup.extensions',
    'rths_numerical.cli',
    'rths_compensator.cli',
    'rths_actuator_bridge.cli',
    'rths_discrepancy.cli',
)

#: Commands that report progress (rths_common.progress) and so take --quiet; every bench does.
PROGRESS_COMMANDS = ('run', 'launch', 'review', 'replay', 'reference', 'identify', 'design',
                     'simulate', 'study', 'fit-mr', 'characterise-dtm', 'discrepancy')

#: Entry-point group through which packages above this one add sub-commands.
ENTRY_POINT_GROUP = 'rths.cli'


def cli_modules() -> list:
    """Return the names of every module that adds sub-commands: ours, then the entry points'."""
    plugins = sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda ep: ep.name)
    return list(dict.fromkeys(list(CLI_MODULES) + [ep.value for ep in plugins]))


def _add_quiet(commands, benches):
    """Give every progress-reporting sub-command (and its own sub-commands) ``--quiet``."""
    from rths_common.progress import add_quiet_argument

    parsers = [commands.choices[name] for name in PROGRESS_COMMANDS if name in commands.choices]
    parsers += list(benches.choices.values())
    while parsers:
        parser = parsers.pop()
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if subs:
            parsers += list(subs[0].choices.values())
        elif not any('--quiet' in a.option_strings for a in parser._actions):
            add_quiet_argument(parser)


def error_line(err) -> str:
    """Return the message of a user error on one line, as ``rths`` prints it."""
    return ' '.join(str(err).split())


class Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line: ``PROG: error: ...`` and the --help hint."""

    def error(self, message):
        """Exit 2 with one line: the error and where to read the command's options."""
        message = message.replace('\r', '\\r').replace('\n', '\\n')  # arguments hold newlines
        self.exit(2, f'{self.prog}: error: {message} (see {self.prog} --help)\n')


def build_parser() -> argparse.ArgumentParser:
    """Create the full ``rths`` argument parser from every package's cli module.

    Every numeric option is refused outside its range (``OPTION_RANGES``) and when not
    finite while parsing, so no command starts on a value it would refuse later.
    """
    from rths_common.params import check_option_ranges
    parser = Parser(
        prog='rths',
        description='Real-time hybrid simulation (RTHS) on ROS 2: run the node graph, '
                    'identify and compensate the actuator, simulate the building, review runs.',
        epilog="Run 'rths COMMAND --help' for the options of one command. Long commands show "
               'their progress (steps, rate, ETA) on stderr: one redrawn line on a terminal, a '
               'plain line per 10 % or 10 s in logs and pipes; --quiet turns it off.')
    commands = parser.add_subparsers(dest='command', metavar='COMMAND')
    commands.required = True
    bench = commands.add_parser(
        'bench', help='benchmarks that measure speed/accuracy targets and save JSON',
        description='Benchmarks: each prints its results and writes them to --out as JSON.')
    benches = bench.add_subparsers(dest='bench', metavar='NAME')
    benches.required = True
    modules = [importlib.import_module(name) for name in cli_modules()]
    for module in modules:
        module.register(commands, benches)
    for module in modules:      # options added to other packages' commands
        if hasattr(module, 'extend'):
            module.extend(commands, benches)
    _add_quiet(commands, benches)
    check_option_ranges(parser)
    return parser


def main(argv=None) -> int:
    """Parse the command line and run the chosen sub-command."""
    parser = build_parser()
    args = parser.parse_args(argv)
    from rths_common.progress import apply_quiet
    apply_quiet(args)
    try:
        return int(args.func(args) or 0)
    except (ValueError, OSError) as err:
        if os.environ.get('RTHS_DEBUG'):
            raise
        print(f'rths {args.command}: error: {error_line(err)}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f'rths {args.command}: interrupted', file=sys.stderr)
        return 130


if __name__ == '__main__':
    sys.exit(main())
