"""ament_pep257 over this package, configured by the checkout's ament_lint.ini."""

from pathlib import Path

import pytest

from rths_common import lint


@pytest.mark.linter
@pytest.mark.pep257
def test_pep257():
    package = Path(__file__).resolve().parents[1]
    assert lint.pep257(package, package / 'test') == 0, 'pep257 errors: see the output above'
