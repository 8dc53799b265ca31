"""Fixtures for the export tests: a small, fully known map snapshot."""

from __future__ import annotations

import math

import numpy as np
import pytest

from shared.pipeline.snapshot import MapSnapshot
from shared.types import Pose2D

SEGMENTS = np.array(
    [
        [0.0, 0.0, 4.0, 0.0],
        [4.0, 0.0, 4.0, 3.0],
        [4.0, 3.0, 0.0, 3.0],
        [-0.000001, 3.0, 0.1, 0.2],
    ]
)
SEGMENT_IDS = np.array([7, 3, 11, 42], dtype=np.intp)
CENTROIDS = np.array([[2.0, 0.05], [3.95, 1.5], [2.0, 2.95]])
TRAJECTORY = np.array(
    [
        [90.239599, 1.0, 1.0, 0.0],
        [90.719599, 1.5, 1.0, 0.25],
        [91.321399, 2.0, 1.5, math.pi / 2],
    ]
)


@pytest.fixture
def snapshot() -> MapSnapshot:
    """Four walls of a 4 m x 3 m room (one slanted), three centroids, three poses; last pose faces +y."""
    return MapSnapshot(
        version=3,
        stamp_s=91.321399,
        segments=SEGMENTS.copy(),
        segment_ids=SEGMENT_IDS.copy(),
        centroids=CENTROIDS.copy(),
        pose=Pose2D(2.0, 1.5, math.pi / 2),
        trajectory=TRAJECTORY.copy(),
    )
