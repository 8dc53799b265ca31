"""What each stage's result must satisfy, as functions that return problems (empty: fine).

Three kinds, all read by the stage descriptions (:mod:`shared.kernels.stages`):

- ``check_*(result, n_in)``: the result's types, shapes, finiteness and invariants for ``n_in`` input
  points (rows of the ``(N, 2)`` input, non-finite rows included); run on every result the conformance
  battery, the dry run and the runtime guard see. O(N + L).
- ``*_on_wall(kernel, result, points)``: what a kernel must find in points along the single wall x = 2 m
  (:func:`shared.kernels.probes.wall_points`): the battery's ``line-1000`` check.
- ``*_skip_nonfinite(result, rows)``: how non-finite input rows ``rows`` must come out: the battery's
  ``nan-inf`` check.

Nothing here raises for a bad result of the right type (the caller catches what is too broken to inspect),
asserts or does I/O.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from shared.kernels.probes import moved_copy
from shared.types import FloatArray, Pose2D

__all__ = [
    "check_clusters",
    "check_lines",
    "check_match",
    "check_noise",
    "check_segments",
    "clusters_on_wall",
    "clusters_skip_nonfinite",
    "lines_on_wall",
    "match_on_wall",
    "noise_skip_nonfinite",
    "nothing_found_needed",
    "nothing_more",
    "segments_on_wall",
]


class _Problems(list[str]):
    def need(self, ok: Any, what: str) -> None:
        if not bool(ok):
            self.append(what)


def check_segments(result: Any, n_in: int) -> list[str]:
    """Segments: points ``(n, 2)`` finite, beam indices and labels ``(n,)``, labels >= -1 and increasing."""
    out = _Problems()
    n = len(result.points)
    out.need(
        result.points.shape == (n, 2) and result.beam_index.shape == (n,) and result.labels.shape == (n,),
        f"Segments shapes points {result.points.shape}, beam_index {result.beam_index.shape}, labels "
        f"{result.labels.shape}: expected ({n}, 2), ({n},), ({n},)",
    )
    out.need(np.all(np.isfinite(result.points)), "Segments.points has non-finite values")
    lab = result.labels[result.labels >= 0]
    out.need(np.all(np.diff(lab) >= 0), "segment labels must increase along the scan")
    out.need(np.all(result.labels >= -1), "Segments.labels has values below -1")
    return out


def check_noise(result: Any, n_in: int) -> list[str]:
    """NoiseResult: ``keep`` bool ``(n_in,)``; finite points ``(M, 2)``, M >= kept; labels ``(M,)`` >= 0."""
    out = _Problems()
    out.need(
        result.keep.shape == (n_in,) and result.keep.dtype == np.bool_,
        f"NoiseResult.keep is {result.keep.dtype} {result.keep.shape}: expected bool ({n_in},)",
    )
    out.need(
        result.points.ndim == 2 and result.points.shape[1] == 2,
        f"NoiseResult.points has shape {result.points.shape}: expected (M, 2)",
    )
    out.need(
        result.points.shape[0] >= int(result.keep.sum()),
        f"NoiseResult.points has {result.points.shape[0]} rows: fewer than the {int(result.keep.sum())} kept",
    )
    out.need(
        result.labels.shape == (result.points.shape[0],),
        f"NoiseResult.labels has shape {result.labels.shape}: expected ({result.points.shape[0]},)",
    )
    out.need(np.all(np.isfinite(result.points)), "NoiseResult.points has non-finite values")
    out.need(np.all(result.labels >= 0), "NoiseResult.labels has negative values")
    return out


def check_clusters(result: Any, n_in: int) -> list[str]:
    """Clusters: finite centroids ``(k, 2)``, labels ``(n_in,)`` in -1..k-1, objective finite >= 0,
    memberships ``(n_in, k)`` when given."""
    out = _Problems()
    k = result.n_clusters
    out.need(
        result.centroids.shape == (k, 2) and np.all(np.isfinite(result.centroids)),
        f"Clusters.centroids has shape {result.centroids.shape} or non-finite values:"
        f" expected finite ({k}, 2)",
    )
    out.need(
        result.labels.shape == (n_in,), f"Clusters.labels has shape {result.labels.shape}: expected ({n_in},)"
    )
    out.need(
        np.all((result.labels >= -1) & (result.labels < max(k, 1))),
        f"Clusters.labels outside -1..{max(k, 1) - 1}",
    )
    out.need(
        math.isfinite(result.objective) and result.objective >= 0.0,
        f"Clusters.objective is {result.objective!r}: expected finite and >= 0",
    )
    if result.memberships is not None:
        out.need(
            result.memberships.shape == (n_in, k),
            f"Clusters.memberships has shape {result.memberships.shape}: expected ({n_in}, {k})",
        )
    return out


def check_lines(result: Any, n_in: int) -> list[str]:
    """Lines: finite segments ``(n, 4)``; rho, theta, group, support ``(n,)``; theta in [0, pi); both end
    points on their line (rho, theta) within 1 micrometre."""
    out = _Problems()
    n = result.n_lines
    out.need(
        result.segments.shape == (n, 4) and np.all(np.isfinite(result.segments)),
        f"Lines.segments has shape {result.segments.shape} or non-finite values: expected finite ({n}, 4)",
    )
    out.need(
        result.rho_m.shape == result.theta_rad.shape == result.group.shape == result.support.shape == (n,),
        f"Lines.rho_m/theta_rad/group/support shapes {result.rho_m.shape}/{result.theta_rad.shape}/"
        f"{result.group.shape}/{result.support.shape}: expected ({n},) each",
    )
    out.need(
        np.all((result.theta_rad >= 0.0) & (result.theta_rad < math.pi)), "Lines.theta_rad outside [0, pi)"
    )
    if not out:  # end points lie on the reported line
        for i, ((x0, y0, x1, y1), rho, th) in enumerate(
            zip(result.segments, result.rho_m, result.theta_rad, strict=True)
        ):
            for x, y in ((x0, y0), (x1, y1)):
                off = abs(x * math.cos(th) + y * math.sin(th) - rho)
                if not off < 1e-6:
                    out.append(f"line {i}: end point ({x}, {y}) is {off} m off its line (rho, theta)")
    return out


def check_match(result: Any, n_in: int) -> list[str]:
    """Match: a Pose2D, inlier ratio in [0, 1], iterations >= 0, RMSE >= 0."""
    out = _Problems()
    out.need(isinstance(result.pose, Pose2D), f"Match.pose is {type(result.pose).__name__}: expected Pose2D")
    out.need(
        0.0 <= result.inlier_ratio <= 1.0 and result.n_iter >= 0,
        f"Match.inlier_ratio {result.inlier_ratio!r} outside [0, 1] or n_iter {result.n_iter!r} < 0",
    )
    out.need(result.rmse_m >= 0.0, f"Match.rmse_m is {result.rmse_m!r}: expected >= 0")
    return out


# ------------------------------------------------------------------------------------ one wall, x = 2 m
def _close(actual: Any, target: float, atol: float) -> bool:
    """``np.testing.assert_allclose(actual, target, atol=atol)`` as a predicate (NaN is never close)."""
    return bool(np.allclose(np.asarray(actual, dtype=np.float64), target, rtol=1e-7, atol=atol))


def nothing_found_needed(kernel: Any, result: Any, points: FloatArray) -> list[str]:
    """No expectation beyond a valid result (noise removal may keep or drop wall points)."""
    return []


def segments_on_wall(kernel: Any, result: Any, points: FloatArray) -> list[str]:
    """At least one segment."""
    return [] if result.n_segments >= 1 else ["found no segment in 1000 points on one wall"]


def clusters_on_wall(kernel: Any, result: Any, points: FloatArray) -> list[str]:
    """Every centroid on the wall (1 cm)."""
    if np.all(np.abs(result.centroids[:, 0] - 2.0) < 0.01):
        return []
    return ["centroids are not on the wall x = 2 m (tolerance 0.01 m)"]


def lines_on_wall(kernel: Any, result: Any, points: FloatArray) -> list[str]:
    """A line; every end point on the wall (3 cm); a fitted line (all but centroid joining, which joins the
    noisy points themselves) within 2 degrees and 3 cm of it."""
    if result.n_lines < 1:
        return ["found no line in 1000 points on one wall"]
    out: list[str] = []
    if not _close(result.segments[:, [0, 2]], 2.0, 0.03):
        out.append("line end points are not on the wall x = 2 m (tolerance 0.03 m)")
    if kernel.name != "centroid-join":
        # a fitted line is the wall: normal along x, i.e. theta ~ 0 (rho ~ 2) or theta ~ pi (rho ~ -2)
        near_pi = result.theta_rad > math.pi / 2
        off_axis = np.where(near_pi, math.pi - result.theta_rad, result.theta_rad)
        if not np.all(off_axis < math.radians(2.0)):
            out.append("fitted line direction is more than 2 deg off the wall's")
        if not _close(np.where(near_pi, -result.rho_m, result.rho_m), 2.0, 0.03):
            out.append("fitted line distance rho is not the wall's 2 m (tolerance 0.03 m)")
    return out


def match_on_wall(kernel: Any, result: Any, points: FloatArray) -> list[str]:
    """Along one wall only its normal offset and direction are observable: the matched current scan must
    land back on the wall (1 cm)."""
    aligned = result.pose.transform_points(moved_copy(points))
    if _close(aligned[:, 0], 2.0, 0.01):
        return []
    return ["the matched current scan does not land back on the wall x = 2 m (tolerance 0.01 m)"]


# ------------------------------------------------------------------------------------ non-finite rows
def nothing_more(result: Any, rows: Sequence[int]) -> list[str]:
    """No expectation beyond a valid result (stages whose input is not a plain point set)."""
    return []


def noise_skip_nonfinite(result: Any, rows: Sequence[int]) -> list[str]:
    """Non-finite rows are never kept."""
    kept = [r for r in rows if result.keep[r]]
    return [f"kept non-finite rows {kept}"] if kept else []


def clusters_skip_nonfinite(result: Any, rows: Sequence[int]) -> list[str]:
    """Non-finite rows are labelled -1."""
    idx = list(rows)
    if np.all(result.labels[idx] == -1):
        return []
    return [f"non-finite rows {idx} labelled {result.labels[idx].tolist()}: expected -1"]
