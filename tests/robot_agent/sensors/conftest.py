"""Fixtures of the URG-04LX tests."""

from __future__ import annotations

import pytest

from shared.sim import SimRun, default_world, simulate_run


@pytest.fixture(scope="session")
def sim_run() -> SimRun:
    """The default world's simulated run: the scans the emulated sensor sees."""
    return simulate_run(default_world(), seed=0)
