"""ament_flake8 over this package, configured by the workspace's ament_lint.ini."""

from pathlib import Path

from ament_flake8.main import main_with_errors
import pytest

PACKAGE = Path(__file__).resolve().parents[1]
CONFIG = PACKAGE.parents[1] / 'ament_lint.ini'


@pytest.mark.flake8
@pytest.mark.linter
def test_flake8():
    rc, errors = main_with_errors(argv=['--config', str(CONFIG), str(PACKAGE)])
    assert rc == 0, f'{len(errors)} flake8 error(s):\n' + '\n'.join(errors)
