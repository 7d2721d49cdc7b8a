"""ament_pep257 over this package, configured by the workspace's ament_lint.ini."""

from configparser import ConfigParser
from pathlib import Path

from ament_pep257.main import main
import pytest

PACKAGE = Path(__file__).resolve().parents[1]
CONFIG = PACKAGE.parents[1] / 'ament_lint.ini'


@pytest.mark.linter
@pytest.mark.pep257
def test_pep257():
    config = ConfigParser()
    config.read(CONFIG)
    conf = config['pep257']
    tests = PACKAGE / 'test'
    code = main(argv=['--convention', conf['convention'], '--add-ignore',
                      *conf['add-ignore'].split(','), '--exclude', str(tests), '--', str(PACKAGE)])
    test = main(argv=['--convention', conf['convention'], '--add-ignore',
                      *conf['add-ignore-tests'].split(','), '--', str(tests)])
    assert (code, test) == (0, 0), 'pep257 docstring errors: see the output above'
