"""Test support of this package: :func:`require_opensees`, the CI rule for OpenSeesPy.

OpenSeesPy is optional for a user (``make setup-opensees``; its licence is not open source
for commercial use) but ``make test`` installs it, so the tests that compare the OpenSees
backend with the built-in one run in CI.  :func:`require_opensees` skips such a test where
OpenSeesPy is absent and fails it in CI (:func:`rths_common.testing.require`).
"""

from rths_common.testing import require

from .opensees_backend import opensees_available


def require_opensees() -> None:
    """Go on if OpenSeesPy imports; else skip (fail in CI) with the reason and the fix."""
    ok, why = opensees_available()
    require(ok, f'OpenSeesPy unavailable: {why}')
