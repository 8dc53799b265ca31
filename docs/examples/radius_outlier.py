"""radius-outlier 1.0.0: an example kernel of a new name, written as the README's "Writing your own" says.

A noise filter that keeps a point when at least ``min_neighbours`` other points lie within ``radius_m`` of
it (a radius outlier filter, as point-cloud tools offer it); every other point, and every non-finite one,
is dropped. ``labels`` are all zero: it does not cluster. Time O(N log N) with scipy's k-d tree.

Sign it with ``linemap keys sign docs/examples/radius_outlier.py --key KEY.pem``, upload it as kernel
``radius-outlier``, stage ``noise-removal``, version ``1.0.0``, install it on a robot
(``<kernel-install stage="noise-removal" name="radius-outlier" version="1.0.0" sha256=".."/>``) and put
it into the noise-removal chain:
``<noise-removal><kernel name="radius-outlier"><param name="radius_m" unit="cm">6</param></kernel>
</noise-removal>``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree

from shared.kernels import NoiseRemovalKernel, param, register
from shared.kernels.params import KernelParams
from shared.kernels.results import NoiseResult, freeze


class RadiusOutlierParams(KernelParams):
    """Parameters of :class:`RadiusOutlier`."""

    radius_m: float = param(
        0.05, description="Neighbourhood radius (distance <= radius counts)", unit="m", ge=1e-3, le=5.0
    )
    min_neighbours: int = param(
        2, description="Other points within radius_m that a point needs to be kept", ge=1, le=100
    )


@register
class RadiusOutlier(NoiseRemovalKernel[RadiusOutlierParams]):
    """Keeps the points with at least ``min_neighbours`` others within ``radius_m``; drops the rest."""

    name = "radius-outlier"
    version = "1.0.0"
    Params = RadiusOutlierParams

    def apply(self, points: ArrayLike) -> NoiseResult:
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        finite = np.isfinite(pts).all(axis=1)
        keep = np.zeros(len(pts), dtype=bool)
        idx = np.flatnonzero(finite)
        if len(idx):
            tree = cKDTree(pts[idx])
            counts = np.asarray(tree.query_ball_point(pts[idx], self.params.radius_m, return_length=True))
            keep[idx] = counts - 1 >= self.params.min_neighbours
        out = pts[keep].copy()
        labels = np.zeros(len(out), dtype=np.intp)
        freeze(keep, out, labels)
        return NoiseResult(keep=keep, points=out, labels=labels)
