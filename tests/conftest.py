"""Fixtures shared by the test files."""
from __future__ import annotations

import pytest


@pytest.fixture(scope="module")
def device():
    """The OpenCL runtime; the test is skipped when no usable device exists."""
    from wavlight import cl
    from wavlight.errors import WavlightError
    try:
        return cl.runtime()
    except WavlightError as e:
        pytest.skip(str(e))
