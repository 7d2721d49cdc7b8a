"""ament_flake8 over this package, configured by the checkout's ament_lint.ini."""

from pathlib import Path

import pytest

from rths_common import lint


@pytest.mark.flake8
@pytest.mark.linter
def test_flake8():
    errors = lint.flake8(Path(__file__).resolve().parents[1])
    assert not errors, f'{len(errors)} flake8 error(s):\n' + '\n'.join(errors)
