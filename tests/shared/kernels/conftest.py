"""Shared fixtures for kernel tests: simulated scans of the default world."""

from __future__ import annotations

import numpy as np
import pytest

from shared.sim import RangeNoise, default_world, simulate_scan
from shared.types import Pose2D, Scan


@pytest.fixture(scope="session")
def room_scan() -> Scan:
    """A URG-04LX scan in the default world with 5 % clutter returns (seeded)."""
    rng = np.random.default_rng(1)
    return simulate_scan(default_world(), Pose2D(4.5, 2.0, np.pi), rng, RangeNoise(outlier_rate=0.05))
