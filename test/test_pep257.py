"""ament_pep257 over the system tests, configured by the workspace's ament_lint.ini."""

from configparser import ConfigParser
from pathlib import Path

from ament_pep257.main import main
import pytest

PACKAGE = Path(__file__).resolve().parent
CONFIG = PACKAGE.parent / 'ament_lint.ini'


@pytest.mark.linter
@pytest.mark.pep257
def test_pep257():
    config = ConfigParser()
    config.read(CONFIG)
    conf = config['pep257']
    # the whole package is tests (rths_system_tests/ holds their shared helpers)
    rc = main(argv=['--convention', conf['convention'], '--add-ignore',
                    *conf['add-ignore-tests'].split(','), '--', str(PACKAGE)])
    assert rc == 0, 'pep257 docstring errors: see the output above'
