"""The analysis tests need openseespy (the `analysis` extra, in `test` too) and, on Debian, the system BLAS its wheel
links against: skipped saying so on a developer's machine without them, failed under CI (CI=true), which installs both."""

import os

import pytest

from fabline.errors import FablineError


@pytest.fixture(scope="session", autouse=True)
def opensees_present():
    from fabline.analysis.solve import opensees
    try:
        opensees()
    except FablineError as missing:
        if os.environ.get("CI"):
            pytest.fail(str(missing))
        pytest.skip(str(missing))
