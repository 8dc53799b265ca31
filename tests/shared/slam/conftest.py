"""Fixtures of the loop-closure tests."""

from __future__ import annotations

import pytest

from tests.shared.slam.slamcheck import LateWorker


@pytest.fixture
def late_worker() -> type[LateWorker]:
    return LateWorker
