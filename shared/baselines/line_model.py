"""Infinite lines seen from a moving scanner: the measurement model of the line-segment EKF-SLAM.

A line is ``(rho, alpha)`` in Hesse normal form, ``rho = x cos(alpha) + y sin(alpha)``, kept normalised as
``rho >= 0`` and ``alpha`` in ``(-pi, pi]`` (the baseline's convention; the pipeline's kernels use
``theta`` in ``[0, pi)`` with a signed ``rho``, and ``(rho, alpha)`` / ``(-rho, alpha + pi)`` are the same
line either way). The robot state is ``(x, y, theta)`` of the robot; the scanner sits at
``robot @ laser_offset`` (:class:`~shared.types.Pose2D` composition), so with offset ``(ox, oy, ot)``::

    xs = x + ox cos(theta) - oy sin(theta),  ys = y + ox sin(theta) + oy cos(theta),  ts = theta + ot

World line -> scanner frame (the prediction ``h``)::

    rho' = rho - xs cos(alpha) - ys sin(alpha),   alpha' = alpha - ts

and its inverse (a new landmark from an observation ``g``)::

    alpha = alpha' + ts,   rho = rho' + xs cos(alpha) + ys sin(alpha)

Every function here is pure, vectorised over lines, and returns the analytic Jacobians. O(lines).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from shared.types import FloatArray, Pose2D

__all__ = ["line_difference", "lines_to_world", "normalise_lines", "predict_lines", "wrap_angles"]


def wrap_angles(angles_rad: ArrayLike) -> FloatArray:
    """Wrap angles to ``(-pi, pi]`` element-wise. O(N)."""
    a = np.asarray(angles_rad, dtype=np.float64)
    w = np.remainder(a + math.pi, 2.0 * math.pi) - math.pi
    return np.asarray(np.where(w <= -math.pi, w + 2.0 * math.pi, w), dtype=np.float64)


def normalise_lines(rho_m: ArrayLike, alpha_rad: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``(rho >= 0, alpha in (-pi, pi])`` for the same lines, and the sign ``s`` applied to ``rho``.

    A line with ``rho < 0`` becomes ``(-rho, alpha + pi)``; a covariance carried along must have its
    ``rho`` row and column multiplied by ``s`` (``-1`` where flipped, else ``+1``). O(N).
    """
    rho = np.asarray(rho_m, dtype=np.float64)
    alpha = np.asarray(alpha_rad, dtype=np.float64)
    sign = np.where(rho < 0.0, -1.0, 1.0)
    return rho * sign, wrap_angles(alpha + np.where(sign < 0.0, math.pi, 0.0)), sign


def line_difference(
    rho_a: ArrayLike, alpha_a: ArrayLike, rho_b: ArrayLike, alpha_b: ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Difference ``a - b`` of lines as ``(d_rho, d_alpha, s)``, broadcasting, with the rho sign flip handled.

    ``b`` is compared in whichever of its two representations ``(rho_b, alpha_b)`` or
    ``(-rho_b, alpha_b + pi)`` has its normal within 90 deg of ``a``'s: ``s`` is ``+1`` or ``-1``
    accordingly, ``d_rho = rho_a - s rho_b`` and ``d_alpha = wrap(alpha_a - alpha_b - (s < 0) pi)``.
    A Jacobian or covariance of ``b`` must have its ``rho`` row scaled by ``s``. This is what makes lines
    through (or near) the scanner, whose normalised ``alpha`` jumps by pi, comparable. O(N).
    """
    ra = np.asarray(rho_a, dtype=np.float64)
    rb = np.asarray(rho_b, dtype=np.float64)
    d_alpha = wrap_angles(np.asarray(alpha_a, dtype=np.float64) - np.asarray(alpha_b, dtype=np.float64))
    flip = np.abs(d_alpha) > 0.5 * math.pi
    sign = np.where(flip, -1.0, 1.0)
    d_alpha = wrap_angles(d_alpha - np.where(flip, math.pi, 0.0))
    return ra - sign * rb, d_alpha, sign


def _sensor(robot: FloatArray, offset: Pose2D) -> tuple[float, float, float, float, float]:
    """Scanner position, heading and d(xs)/d(theta), d(ys)/d(theta) for robot state ``(x, y, theta)``."""
    x, y, th = float(robot[0]), float(robot[1]), float(robot[2])
    c, s = math.cos(th), math.sin(th)
    ox, oy = offset.x_m, offset.y_m
    xs = x + ox * c - oy * s
    ys = y + ox * s + oy * c
    return xs, ys, th + offset.theta_rad, -ox * s - oy * c, ox * c - oy * s


def predict_lines(
    robot: ArrayLike, laser_offset: Pose2D, rho_m: ArrayLike, alpha_rad: ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """World lines seen from the scanner: ``h`` (L, 2) ``[rho', alpha']``, Jacobians ``H_r``, ``H_l``.

    ``rho'`` is signed (not normalised; compare with :func:`line_difference`), ``alpha'`` wrapped.
    ``H_r = d h / d(x, y, theta)`` (L, 2, 3) and ``H_l = d h / d(rho, alpha)`` (L, 2, 2) (module
    docstring). O(L).
    """
    rho = np.asarray(rho_m, dtype=np.float64).reshape(-1)
    alpha = np.asarray(alpha_rad, dtype=np.float64).reshape(-1)
    xs, ys, ts, dxs, dys = _sensor(np.asarray(robot, dtype=np.float64), laser_offset)
    c, s = np.cos(alpha), np.sin(alpha)
    n = rho.size
    h = np.empty((n, 2))
    h[:, 0] = rho - xs * c - ys * s
    h[:, 1] = wrap_angles(alpha - ts)
    H_r = np.zeros((n, 2, 3))
    H_r[:, 0, 0] = -c
    H_r[:, 0, 1] = -s
    H_r[:, 0, 2] = -(dxs * c + dys * s)
    H_r[:, 1, 2] = -1.0
    H_l = np.zeros((n, 2, 2))
    H_l[:, 0, 0] = 1.0
    H_l[:, 0, 1] = xs * s - ys * c
    H_l[:, 1, 1] = 1.0
    return h, H_r, H_l


def lines_to_world(
    robot: ArrayLike, laser_offset: Pose2D, rho_m: ArrayLike, alpha_rad: ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Scanner-frame lines in the world: ``g`` (M, 2) normalised ``[rho, alpha]``, Jacobians ``G_r``, ``G_z``.

    ``G_r = d g / d(x, y, theta)`` (M, 2, 3) and ``G_z = d g / d(rho', alpha')`` (M, 2, 2), for the
    normalised result (the ``rho`` rows are negated where normalising flipped the line). O(M).
    """
    rho_s = np.asarray(rho_m, dtype=np.float64).reshape(-1)
    alpha_s = np.asarray(alpha_rad, dtype=np.float64).reshape(-1)
    xs, ys, ts, dxs, dys = _sensor(np.asarray(robot, dtype=np.float64), laser_offset)
    alpha = alpha_s + ts
    c, s = np.cos(alpha), np.sin(alpha)
    rho = rho_s + xs * c + ys * s
    along = -xs * s + ys * c  # d rho / d alpha
    m = rho_s.size
    G_r = np.zeros((m, 2, 3))
    G_r[:, 0, 0] = c
    G_r[:, 0, 1] = s
    G_r[:, 0, 2] = dxs * c + dys * s + along
    G_r[:, 1, 2] = 1.0
    G_z = np.zeros((m, 2, 2))
    G_z[:, 0, 0] = 1.0
    G_z[:, 0, 1] = along
    G_z[:, 1, 1] = 1.0
    rho_n, alpha_n, sign = normalise_lines(rho, alpha)
    G_r[:, 0, :] *= sign[:, None]
    G_z[:, 0, :] *= sign[:, None]
    return np.stack([rho_n, alpha_n], axis=1), G_r, G_z
