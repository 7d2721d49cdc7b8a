"""ament_pep257 over the system tests, configured by the checkout's ament_lint.ini."""

from pathlib import Path

import pytest

from rths_common import lint


@pytest.mark.linter
@pytest.mark.pep257
def test_pep257():
    package = Path(__file__).resolve().parent   # all tests (rths_system_tests/: their helpers)
    assert lint.pep257(package, package) == 0, 'pep257 errors: see the output above'
