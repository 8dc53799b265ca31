"""What each pipeline stage returns: frozen dataclasses of read-only arrays (SI units)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shared.types import BoolArray, FloatArray, IntArray, Pose2D

__all__ = ["Clusters", "Lines", "Match", "NoiseResult", "Segments", "freeze"]


def freeze(*arrays: np.ndarray) -> None:
    """Mark arrays read-only so a result cannot be changed after it is returned."""
    for arr in arrays:
        arr.setflags(write=False)


@dataclass(frozen=True, slots=True)
class Segments:
    """Segmentation of one scan (paper §3.1).

    ``points`` are the valid returns in the scanner frame, in beam order, with their ``beam_index``;
    ``labels[i]`` is the segment of point ``i`` (``0..n_segments-1``, increasing along the scan) or ``-1``
    when it belongs to no segment (an isolated return or a piece shorter than the minimum).
    """

    points: FloatArray
    beam_index: IntArray
    labels: IntArray

    @property
    def n_segments(self) -> int:
        """Number of segments."""
        return int(self.labels.max()) + 1 if self.labels.size and self.labels.max() >= 0 else 0


@dataclass(frozen=True, slots=True)
class NoiseResult:
    """Noise removal (paper §3.2).

    ``keep[i]`` tells whether input point ``i`` survived; ``points`` is the output point set: the kept input
    points in input order, then any points the kernel added (dilation fills grid cells). ``labels`` gives a
    cluster id per output point for kernels that cluster (DBSCAN), else all zeros; ``-1`` never appears.
    """

    keep: BoolArray
    points: FloatArray
    labels: IntArray

    @property
    def n_added(self) -> int:
        """Points the kernel added that were not in its input."""
        return int(self.points.shape[0] - np.count_nonzero(self.keep))


@dataclass(frozen=True, slots=True)
class Clusters:
    """Partition of points into clusters (paper §3.3).

    ``centroids`` is ``(k, 2)``; ``labels[i]`` is the cluster of point ``i`` (the highest membership for
    FCM) or ``-1`` for a non-finite input point; ``objective`` is eq. 24 (k-means) or eq. 25 (FCM);
    ``memberships`` is the ``(N, k)`` fuzzy partition for FCM, else ``None``.
    """

    centroids: FloatArray
    labels: IntArray
    objective: float
    n_iter: int
    memberships: FloatArray | None = None

    @property
    def n_clusters(self) -> int:
        """Number of clusters found (at most the number of distinct finite points)."""
        return int(self.centroids.shape[0])


@dataclass(frozen=True, slots=True)
class Lines:
    """Straight lines (paper §3.4, §4): ``segments`` ``(L, 4)`` ``[x0, y0, x1, y1]`` and their Hesse form.

    ``rho_m``, ``theta_rad``: the infinite line (``theta`` in ``[0, pi)``); the segment is its span over
    the points it came from. ``group[l]`` is the input group of line ``l``; ``support[l]`` counts its points.
    """

    segments: FloatArray
    rho_m: FloatArray
    theta_rad: FloatArray
    group: IntArray
    support: IntArray

    @property
    def n_lines(self) -> int:
        """Number of lines."""
        return int(self.segments.shape[0])


@dataclass(frozen=True, slots=True)
class Match:
    """Scan-matching result (paper §6.2.2).

    ``pose`` maps the current scan's points into the reference scan's frame; ``rmse_m`` is the root mean
    square distance of the inlier correspondences; ``inlier_ratio`` the share of current points matched
    within the correspondence distance; ``converged`` whether the update fell below the tolerance.
    """

    pose: Pose2D
    rmse_m: float
    inlier_ratio: float
    n_iter: int
    converged: bool
