"""ament's linters with the workspace's configuration, for the packages' lint tests.

Every package's ``test/test_flake8.py`` and ``test/test_pep257.py`` call these
(as ros2/demos' packages call ament_flake8 and ament_pep257 directly) with the
package's directory; the configuration is ``ament_lint.ini`` at the top of the
checkout, found above the package (its comments say why it is what it is).
``ament_flake8`` and ``ament_pep257`` are test dependencies, imported here only
when a test runs.
"""

from configparser import ConfigParser
from pathlib import Path

CONFIG_NAME = 'ament_lint.ini'


def config_path(package: Path) -> Path:
    """Return the ``ament_lint.ini`` of the checkout holding ``package`` (OSError if none)."""
    for folder in Path(package).resolve().parents:
        if (folder / CONFIG_NAME).is_file():
            return folder / CONFIG_NAME
    raise OSError(f'no {CONFIG_NAME} above {package}: run the lint tests from the checkout')


def flake8(package: Path) -> list:
    """Run ament_flake8 over ``package``; return its errors (empty: clean)."""
    # lazy: optional dependency (ament_flake8)
    from ament_flake8.main import main_with_errors

    rc, errors = main_with_errors(argv=['--config', str(config_path(package)), str(package)])
    return list(errors) if rc else []


def pep257(package: Path, tests: Path) -> int:
    """Run ament_pep257 over ``package`` (``tests`` with the tests' ignores); 0 if clean."""
    # lazy: optional dependency (ament_pep257)
    from ament_pep257.main import main

    config = ConfigParser()
    config.read(config_path(package))
    conf = config['pep257']

    def run(ignore: str, *paths) -> int:
        return main(argv=['--convention', conf['convention'], '--add-ignore',
                          *conf[ignore].split(','), *paths])

    code = 0
    if Path(package).resolve() != Path(tests).resolve():
        code = run('add-ignore', '--exclude', str(tests), '--', str(package))
    return code or run('add-ignore-tests', '--', str(tests))
