"""Sub-commands this package adds to the ``rths`` command (see rths_bringup.cli)."""


def register(commands, benches):
    """Add this package's ``rths <command>`` and ``rths bench <name>`` parsers."""
