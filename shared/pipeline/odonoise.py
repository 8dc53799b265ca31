"""How noisy this robot's odometry really is, learned online from the scan matches (docs/worlds.md).

Fusing a scan match with odometry (:mod:`shared.pipeline.fusion`) needs odometry's covariance. A fixed
model cannot fit every robot: the simulator's wheels are good to a centimetre over a metre, the benchmark
logs' odometry is off by decimetres (Freiburg 079's raw odometry has a relation error of 6.5 m against the
pipeline's 0.05 m), and fused under the simulator's figures it pulled the logs' poses off. So the model's
standard deviations (:func:`shared.pipeline.fusion_solve.odometry_information`) are scaled by factors learned
from the innovations ``e = match - odometry`` of the matches the pipeline believed, in the directions the
scan fixes far better than odometry does (its posterior variance there below ``scan_share`` of the
model's), where ``e`` is odometry's own error:

* heading: ``r = e_theta^2 / var_odo_theta``;
* translation: along the scan's best constrained direction ``u`` (the smallest eigenvalue of its
  translation covariance), ``r = (u . e_xy)^2 / var_odo_xy``.

Under a right model each ``r`` is ``chi^2(1)``-distributed, whose median is 0.455; the variance factor is
the median of the last ``window`` ratios over 0.455 (a median, so the few stalls and slip bursts that the
fusion's robust (Huber) term handles do not inflate the noise of the rest), the prior model (factor 1)
until ``min_samples`` ratios are in, and clamped to ``[floor, ceiling]``. The learned state is separate
from the settings (:class:`OdometryNoise` is owned by one pipeline); O(log window) to find a ratio's rank
in the sorted window per update, O(1) for the median.
"""

from __future__ import annotations

from bisect import bisect_left, insort
from collections import deque
from dataclasses import dataclass

import numpy as np

from shared.types import FloatArray

__all__ = ["NoiseScale", "OdometryNoise"]

_CHI2_1_MEDIAN = 0.454936


@dataclass(frozen=True, slots=True)
class NoiseScale:
    """Variance factors for odometry's translation and heading (1: the model as configured)."""

    translation: float = 1.0
    heading: float = 1.0


class OdometryNoise:
    """Learned variance factors of odometry's noise model (module docstring). Not thread-safe."""

    def __init__(
        self,
        *,
        window: int = 200,
        min_samples: int = 20,
        scan_share: float = 0.25,
        floor: float = 0.05,
        ceiling: float = 1e4,
    ) -> None:
        self._window = window
        self._xy: tuple[deque[float], list[float]] = (deque(), [])  # arrival order, sorted
        self._th: tuple[deque[float], list[float]] = (deque(), [])
        self._min = min_samples
        self._share = scan_share
        self._floor = floor
        self._ceiling = ceiling
        self._scale = NoiseScale()

    @property
    def scale(self) -> NoiseScale:
        """The factors in force now."""
        return self._scale

    @property
    def samples(self) -> tuple[int, int]:
        """How many translation and heading ratios the factors rest on (at most ``window`` each)."""
        return len(self._xy[0]), len(self._th[0])

    def ratios(
        self, innovation: FloatArray, scan_information: FloatArray, odometry_information: FloatArray
    ) -> tuple[float | None, float | None]:
        """The translation and heading ratios ``r`` of one match (module docstring), ``None`` where the scan
        does not fix that part far better than odometry: ``innovation`` ``(3,)`` = match minus odometry
        motion ``(x_m, y_m, theta_rad)``, the scan's information ``(3, 3)`` at the match and the *model's*
        (unscaled) odometry information ``(3, 3)`` (diagonal, isotropic in translation). O(1)."""
        try:
            cov = np.linalg.inv(scan_information)
        except np.linalg.LinAlgError:
            return None, None
        var_xy = 1.0 / float(odometry_information[0, 0])
        var_th = 1.0 / float(odometry_information[2, 2])
        r_th = float(innovation[2]) ** 2 / var_th if cov[2, 2] < self._share * var_th else None
        w, v = np.linalg.eigh(cov[:2, :2])
        r_xy = float(v[:, 0] @ innovation[:2]) ** 2 / var_xy if w[0] < self._share * var_xy else None
        return r_xy, r_th

    def consistency(self, r_xy: float | None, r_th: float | None) -> tuple[float, int]:
        """``(m2, dof)``: the squared Mahalanobis distance of a match's ratios under the learned factors
        and how many parts it has (``chi^2(dof)`` if odometry is right). O(1)."""
        k = self._scale
        parts = [(r, f) for r, f in ((r_xy, k.translation), (r_th, k.heading)) if r is not None]
        return sum(r / f for r, f in parts), len(parts)

    def update(self, r_xy: float | None, r_th: float | None) -> None:
        """Add one believed match's ratios (:meth:`ratios`). O(window)."""
        if r_th is None and r_xy is None:
            return
        if r_th is not None:
            self._push(self._th, r_th)
        if r_xy is not None:
            self._push(self._xy, r_xy)
        self._scale = NoiseScale(self._factor(self._xy[1]), self._factor(self._th[1]))

    def _push(self, ratios: tuple[deque[float], list[float]], value: float) -> None:
        """Add ``value`` to the window, dropping the oldest beyond ``window``; O(window) memmove at worst."""
        order, ranked = ratios
        order.append(value)
        insort(ranked, value)
        if len(order) > self._window:
            del ranked[bisect_left(ranked, order.popleft())]

    def _factor(self, ranked: list[float]) -> float:
        n = len(ranked)
        if n < self._min:
            return 1.0
        median = ranked[n // 2] if n % 2 else 0.5 * (ranked[n // 2 - 1] + ranked[n // 2])
        return min(max(median / _CHI2_1_MEDIAN, self._floor), self._ceiling)
