"""Geometry helpers for the straight-line kernel tests: points on known lines, line comparisons."""

from __future__ import annotations

import math

import numpy as np

from shared.kernels import Lines
from shared.types import FloatArray

__all__ = [
    "angle_diff",
    "assert_lines_valid",
    "line_points",
    "max_distance",
]


def line_points(
    rho: float,
    theta: float,
    t0: float,
    t1: float,
    n: int,
    noise_m: float = 0.0,
    seed: int = 0,
) -> FloatArray:
    """``n`` points on the line ``(rho, theta)`` between line parameters ``t0..t1`` (evenly spaced),
    with Gaussian noise of ``noise_m`` along the normal."""
    rng = np.random.default_rng(seed)
    t = np.linspace(t0, t1, n)
    normal = np.array([math.cos(theta), math.sin(theta)])
    direction = np.array([-math.sin(theta), math.cos(theta)])
    offset = rho + (rng.normal(0.0, noise_m, n) if noise_m > 0 else np.zeros(n))
    return np.asarray(offset[:, None] * normal + t[:, None] * direction)


def angle_diff(a: float, b: float) -> float:
    """Smallest difference between two line angles, modulo pi (radians, >= 0)."""
    d = (a - b) % math.pi
    return min(d, math.pi - d)


def max_distance(points: FloatArray, rho: float, theta: float) -> float:
    """Largest orthogonal distance of ``points`` to the line ``(rho, theta)``."""
    return float(np.max(np.abs(points[:, 0] * math.cos(theta) + points[:, 1] * math.sin(theta) - rho)))


def assert_lines_valid(lines: Lines) -> None:
    """Shapes, theta in [0, pi), finite values, end points on their line, read-only arrays."""
    n = lines.n_lines
    assert lines.segments.shape == (n, 4)
    assert lines.rho_m.shape == lines.theta_rad.shape == lines.group.shape == lines.support.shape == (n,)
    assert np.all(np.isfinite(lines.segments))
    assert np.all(np.isfinite(lines.rho_m))
    assert np.all((lines.theta_rad >= 0.0) & (lines.theta_rad < math.pi))
    assert np.all(lines.support >= 1)
    c, s = np.cos(lines.theta_rad), np.sin(lines.theta_rad)
    for x, y in ((0, 1), (2, 3)):
        residual = lines.segments[:, x] * c + lines.segments[:, y] * s - lines.rho_m
        np.testing.assert_allclose(residual, 0.0, atol=1e-9)
    for arr in (lines.segments, lines.rho_m, lines.theta_rad, lines.group, lines.support):
        assert not arr.flags.writeable
