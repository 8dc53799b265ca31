"""Absolute trajectory error: how far estimated robot positions are from the true ones, pose by pose.

The estimate and the truth must share a frame (a simulated run's odometry and the pipeline both start at
the true first pose), so no alignment is fitted: an alignment would hide a drift that starts at step 0.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import ArrayLike

from shared.metrics.errors import MetricInputError

__all__ = ["TrajectoryError", "absolute_trajectory_error"]


@dataclass(frozen=True, slots=True)
class TrajectoryError:
    """Position error (m) over ``poses`` poses: root mean square, mean and maximum; heading error (rad)
    as root mean square of the wrapped difference."""

    rmse_m: float
    mean_m: float
    max_m: float
    heading_rmse_rad: float
    poses: int

    def as_dict(self) -> dict[str, float | int]:
        """The fields as a plain dict (for JSON and tables)."""
        return asdict(self)


def _poses(name: str, value: ArrayLike) -> np.ndarray:
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3 or len(arr) == 0 or not np.all(np.isfinite(arr)):
        raise MetricInputError(
            f"{name} has shape {arr.shape}: expected finite (N, 3) rows [x_m, y_m, theta_rad]"
        )
    return arr


def absolute_trajectory_error(estimate: ArrayLike, truth: ArrayLike) -> TrajectoryError:
    """Compare ``estimate`` with ``truth``, both ``(N, 3)`` rows ``[x_m, y_m, theta_rad]``, pose by pose.
    O(N)."""
    est, true = _poses("estimate", estimate), _poses("truth", truth)
    if est.shape != true.shape:
        raise MetricInputError(f"estimate has {len(est)} poses and truth {len(true)}: expected as many")
    d = np.hypot(est[:, 0] - true[:, 0], est[:, 1] - true[:, 1])
    dth = np.remainder(est[:, 2] - true[:, 2] + math.pi, 2.0 * math.pi) - math.pi
    return TrajectoryError(
        rmse_m=float(np.sqrt(np.mean(d * d))),
        mean_m=float(d.mean()),
        max_m=float(d.max()),
        heading_rmse_rad=float(np.sqrt(np.mean(dth * dth))),
        poses=len(d),
    )
