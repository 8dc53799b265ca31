"""Scan record and URG-04LX geometry (docs/design.md §3)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from shared.errors import InvalidInputError
from shared.types import URG04LX, Scan


def test_urg04lx_geometry() -> None:
    assert URG04LX.beam_count == 682
    assert math.isclose(math.degrees(URG04LX.angle_increment_rad), 360 / 1024)
    angles = np.degrees(URG04LX.angles_rad())
    assert math.isclose(angles[0], -119.53125, abs_tol=1e-9)
    assert math.isclose(angles[-1], (725 - 384) * 360 / 1024, abs_tol=1e-9)
    assert math.isclose(angles[384 - 44], 0.0, abs_tol=1e-12)


def test_scan_is_immutable_and_validates() -> None:
    ranges = np.full(682, 2.0)
    scan = Scan.from_geometry(URG04LX, ranges)
    ranges[0] = 99.0
    assert scan.ranges_m[0] == 2.0, "the scan keeps its own copy"
    with pytest.raises(ValueError, match="read-only"):
        scan.ranges_m[0] = 1.0
    with pytest.raises(InvalidInputError, match="expected 682"):
        Scan.from_geometry(URG04LX, np.ones(10))
    with pytest.raises(InvalidInputError, match="range window"):
        Scan(0.0, 0.0, 0.01, 5.0, 1.0, np.ones(3))


def test_invalid_returns_are_dropped() -> None:
    ranges = np.full(682, 2.0)
    ranges[:5] = [np.nan, np.inf, 0.0, 0.01, 9.0]
    pts, idx = Scan.from_geometry(URG04LX, ranges).to_points()
    assert len(pts) == 677 and idx[0] == 5
    np.testing.assert_allclose(np.hypot(pts[:, 0], pts[:, 1]), 2.0)
    front = pts[idx == 384 - 44][0]
    np.testing.assert_allclose(front, [2.0, 0.0], atol=1e-12)
