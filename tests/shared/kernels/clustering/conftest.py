"""Fixtures for the clustering kernels: simulated URG-04LX scans of a room, and separated blobs."""

from __future__ import annotations

import numpy as np
import pytest

from shared.types import FloatArray

#: An 8 m x 6 m room with a 0.6 m pillar: ``[x0, y0, x1, y1]`` walls in metres.
_OUTLINE = [(0.0, 0.0), (8.0, 0.0), (8.0, 6.0), (0.0, 6.0)]
_PILLAR = [(5.0, 3.5), (5.6, 3.5), (5.6, 4.1), (5.0, 4.1)]


def _walls() -> FloatArray:
    parts = []
    for poly in (_OUTLINE, _PILLAR):
        v = np.asarray(poly, dtype=np.float64)
        parts.append(np.hstack([v, np.roll(v, -1, axis=0)]))
    return np.vstack(parts)


def simulate_scan(rng: np.random.Generator, pose: tuple[float, float, float]) -> FloatArray:
    """One URG-04LX scan (682 beams from -119.5 deg, 360/1024 deg apart) in the world frame.

    Walls 1-5 m away, Gaussian range noise sigma 1 cm, 5 % outlier returns in front of the wall.
    """
    x0, y0, th = pose
    local = np.deg2rad(-119.5) + np.arange(682) * (2.0 * np.pi / 1024.0)
    ang = local + th
    walls = _walls()
    dx, dy = np.cos(ang)[:, None], np.sin(ang)[:, None]
    ax, ay = walls[:, 0] - x0, walls[:, 1] - y0
    ex, ey = walls[:, 2] - walls[:, 0], walls[:, 3] - walls[:, 1]
    den = dx * ey - dy * ex
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ax * ey - ay * ex) / den
        u = (ax * dy - ay * dx) / den
    hit = (np.abs(den) > 1e-12) & (t > 0.0) & (u >= 0.0) & (u <= 1.0)
    r = np.where(hit, t, np.inf).min(axis=1)
    r = r + rng.normal(0.0, 0.01, r.size)
    out = rng.random(r.size) < 0.05
    r[out] = rng.uniform(0.1, r[out])
    keep = (r > 0.02) & (r < 5.6)
    return np.column_stack([x0 + r[keep] * np.cos(ang[keep]), y0 + r[keep] * np.sin(ang[keep])])


@pytest.fixture(scope="session")
def room_scan() -> FloatArray:
    """One scan, ~680 points (the online step)."""
    return simulate_scan(np.random.default_rng(0), (3.0, 2.5, 0.3))


@pytest.fixture(scope="session")
def room_batch() -> FloatArray:
    """Nine scans from slightly moved poses, ~6,100 points (the offline batch)."""
    rng = np.random.default_rng(0)
    scans = [simulate_scan(rng, (3.0 + 0.05 * i, 2.5 + 0.03 * i, 0.3 + 0.02 * i)) for i in range(9)]
    return np.vstack(scans)


@pytest.fixture(scope="session")
def blobs() -> tuple[FloatArray, np.ndarray]:
    """Five tight blobs (sigma 2 cm) 1 m apart or more, 40 points each: points and true labels."""
    rng = np.random.default_rng(7)
    centres = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.5], [2.5, 2.0], [-1.0, 3.0]])
    truth = np.repeat(np.arange(5), 40)
    pts = centres[truth] + rng.normal(0.0, 0.02, (truth.size, 2))
    order = rng.permutation(truth.size)
    return pts[order], truth[order]
