"""Line extraction from one scan by split-and-merge, the classic front end of line-based EKF-SLAM.

1. **Clusters**: consecutive points (in beam order) farther apart than
   ``break_distance_m + break_range_ratio * range`` start a new cluster.
2. **Split** (iterative end-point fit): a cluster is cut at the point farthest from the chord between its
   first and last points while that distance exceeds the split threshold
   ``split_threshold_m + split_range_ratio * range`` of that point (range-dependent because the URG-04LX's
   noise grows as 2.5 % of the range beyond 1 m). The cut point goes to both halves.
3. **Fit** each piece by total least squares (below), once more after dropping points farther from the
   line than their split threshold (a clutter spike inside a wall). Pieces with fewer than ``min_points``
   inliers or shorter than ``min_length_m`` are dropped.
4. **Merge** neighbours in scan order whose facing ends are at most ``merge_gap_m`` apart and whose lines
   agree statistically: ``d^T (C_a + C_b)^-1 d <= merge_chi2`` for ``d = (d_rho, d_alpha)`` and the two
   fits' covariances ``C``. The union is refitted. Repeated until nothing merges. (Collinear pieces
   farther apart stay separate observations, so a doorway is not bridged.)

**Total least squares** (Arras & Siegwart 1997): with centroid ``c`` and centred scatter sums
``Sxx, Syy, Sxy``, the normal angle is ``alpha = atan2(-2 Sxy, Syy - Sxx) / 2`` and ``rho = c . n``
(then normalised to ``rho >= 0``), which minimises the sum of squared orthogonal residuals
``r_i = p_i . n - rho``.

**Covariance** of ``(rho, alpha)``, a simple first-order model: points have independent orthogonal noise
of variance ``s^2 = max(sum r_i^2 / (N - 2), sigma_floor_m^2)``; with ``t_i`` the points' coordinates along
the line direction ``d = (-sin alpha, cos alpha)`` and ``t_c = c . d``::

    var(alpha) = s^2 / sum (t_i - t_c)^2
    var(rho)   = s^2 / N + t_c^2 var(alpha),     cov(rho, alpha) = t_c var(alpha)

Cost: O(N) for clustering, O(N log N) typical (O(N^2) worst case) for splitting, O(N) per merge pass.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
from numpy.typing import ArrayLike

from shared.baselines.errors import check_number
from shared.baselines.line_model import line_difference, normalise_lines
from shared.types import FloatArray, IntArray, Scan, as_points

__all__ = ["LineObservations", "SplitMergeParams", "extract_lines", "fit_line", "split_and_merge"]


@dataclass(frozen=True, slots=True)
class SplitMergeParams:
    """Settings of :func:`split_and_merge` (lengths in metres, ratios in metres per metre of range)."""

    break_distance_m: float = 0.15
    break_range_ratio: float = 0.03
    split_threshold_m: float = 0.03
    split_range_ratio: float = 0.05
    min_points: int = 10
    min_length_m: float = 0.3
    max_alpha_sigma_rad: float = 0.05
    min_incidence_deg: float = 15.0
    merge_gap_m: float = 0.5
    merge_chi2: float = 13.8
    sigma_floor_m: float = 0.005

    def __post_init__(self) -> None:
        owner = type(self).__name__
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "min_points":
                check_number(owner, f.name, value, minimum=3, inclusive=True, integer=True)
            elif f.name.endswith("_ratio") or f.name == "merge_gap_m":
                check_number(owner, f.name, value, inclusive=True)
            elif f.name == "min_incidence_deg":
                check_number(owner, f.name, value, inclusive=True, maximum=90.0)
            else:
                check_number(owner, f.name, value)


@dataclass(frozen=True, slots=True)
class LineObservations:
    """Lines seen in one scan, in the scanner frame; M rows, one per line.

    ``rho_m`` ``(M,)`` >= 0 and ``alpha_rad`` ``(M,)`` in ``(-pi, pi]`` (Hesse normal form),
    ``covariance`` ``(M, 2, 2)`` of ``(rho, alpha)``, ``endpoints`` ``(M, 4)`` ``[x0, y0, x1, y1]`` (the first
    and last inlier projected on the line, in beam order), ``n_points`` ``(M,)`` inliers, ``rms_m`` ``(M,)``
    orthogonal residual.
    """

    rho_m: FloatArray
    alpha_rad: FloatArray
    covariance: FloatArray
    endpoints: FloatArray
    n_points: IntArray
    rms_m: FloatArray

    def __len__(self) -> int:
        return int(self.rho_m.size)

    @classmethod
    def empty(cls) -> LineObservations:
        """No lines."""
        return cls(
            np.zeros(0),
            np.zeros(0),
            np.zeros((0, 2, 2)),
            np.zeros((0, 4)),
            np.zeros(0, dtype=np.intp),
            np.zeros(0),
        )

    @property
    def lengths_m(self) -> FloatArray:
        """Length of each observed piece ``(M,)``."""
        e = self.endpoints
        return np.asarray(np.hypot(e[:, 2] - e[:, 0], e[:, 3] - e[:, 1]))


@dataclass(frozen=True, slots=True)
class _Fit:
    first: int  # index range [first, last] in the cleaned point array
    last: int
    rho: float
    alpha: float
    cov: FloatArray
    ends: FloatArray
    n: int
    rms: float


def fit_line(points: FloatArray, sigma_floor_m: float = 0.005) -> tuple[float, float, FloatArray, float]:
    """Total least squares line through ``(N, 2)`` points (N >= 2): ``(rho, alpha, covariance (2, 2), rms)``.

    See the module docstring for the equations and the covariance model. O(N).
    """
    c = points.mean(axis=0)
    q = points - c
    sxx = float(np.dot(q[:, 0], q[:, 0]))
    syy = float(np.dot(q[:, 1], q[:, 1]))
    sxy = float(np.dot(q[:, 0], q[:, 1]))
    alpha = 0.5 * math.atan2(-2.0 * sxy, syy - sxx)
    rho_a, alpha_a, _ = normalise_lines(float(c[0] * math.cos(alpha) + c[1] * math.sin(alpha)), alpha)
    rho, alpha = float(rho_a), float(alpha_a)
    ca, sa = math.cos(alpha), math.sin(alpha)
    r = points[:, 0] * ca + points[:, 1] * sa - rho
    n = len(points)
    rms = math.sqrt(float(np.dot(r, r)) / n)
    var = max(float(np.dot(r, r)) / max(n - 2, 1), sigma_floor_m**2)
    spread = sxx * sa * sa - 2.0 * sxy * sa * ca + syy * ca * ca
    var_a = var / max(spread, 1e-12)
    tc = float(-c[0] * sa + c[1] * ca)
    cov = np.array([[var / n + tc * tc * var_a, tc * var_a], [tc * var_a, var_a]])
    return rho, alpha, cov, rms


def _split(pts: FloatArray, thr: FloatArray, first: int, last: int, out: list[tuple[int, int]]) -> None:
    """Iterative end-point fit of ``pts[first..last]``; appends the final index ranges to ``out``."""
    stack = [(first, last)]
    while stack:
        a, b = stack.pop()
        if b - a < 2:
            out.append((a, b))
            continue
        p0, p1 = pts[a], pts[b]
        seg = p1 - p0
        length = math.hypot(float(seg[0]), float(seg[1]))
        inner = pts[a + 1 : b] - p0
        if length < 1e-12:
            dist = np.hypot(inner[:, 0], inner[:, 1])
        else:
            dist = np.abs(inner[:, 0] * seg[1] - inner[:, 1] * seg[0]) / length
        excess = dist - thr[a + 1 : b]
        k = int(np.argmax(excess))
        if excess[k] > 0.0:
            cut = a + 1 + k
            stack.append((cut, b))
            stack.append((a, cut))
        else:
            out.append((a, b))


def _fit_piece(pts: FloatArray, thr: FloatArray, first: int, last: int, p: SplitMergeParams) -> _Fit | None:
    """Fit ``pts[first..last]`` with one trimming pass; ``None`` if fewer than 3 inliers."""
    if last - first + 1 < 3:
        return None
    piece = pts[first : last + 1]
    rho, alpha, cov, rms = fit_line(piece, p.sigma_floor_m)
    r = piece[:, 0] * math.cos(alpha) + piece[:, 1] * math.sin(alpha) - rho
    keep = np.abs(r) <= thr[first : last + 1]
    if int(keep.sum()) < 3:
        return None
    if not bool(keep.all()):
        piece = piece[keep]
        rho, alpha, cov, rms = fit_line(piece, p.sigma_floor_m)
    n = np.array([math.cos(alpha), math.sin(alpha)])
    ends = np.stack([piece[0], piece[-1]])
    ends = ends - np.outer(ends @ n - rho, n)
    return _Fit(first, last, rho, alpha, cov, ends.reshape(4), len(piece), rms)


def _good(f: _Fit, p: SplitMergeParams) -> bool:
    """Enough inliers, long enough, a well-determined angle, and not seen edge-on."""
    ends = f.ends.reshape(2, 2)
    if f.n < p.min_points or math.hypot(*(ends[1] - ends[0])) < p.min_length_m:
        return False
    if f.cov[1, 1] > p.max_alpha_sigma_rad**2:
        return False
    # the line's normal against the ray to its middle: a line seen edge-on (or the range noise along the
    # beams of a short piece, which a fit may take for a line) is refused
    mid = 0.5 * (ends[0] + ends[1])
    cos_inc = abs(float(mid[0] * math.cos(f.alpha) + mid[1] * math.sin(f.alpha)))
    return cos_inc >= math.sin(math.radians(p.min_incidence_deg)) * max(math.hypot(*mid), 1e-12)


def _mergeable(a: _Fit, b: _Fit, p: SplitMergeParams) -> bool:
    gap = math.hypot(float(b.ends[0] - a.ends[2]), float(b.ends[1] - a.ends[3]))
    if gap > p.merge_gap_m:
        return False
    d_rho, d_alpha, sign = line_difference(a.rho, a.alpha, b.rho, b.alpha)
    s = float(sign)
    cov = a.cov + np.array([[b.cov[0, 0], s * b.cov[0, 1]], [s * b.cov[1, 0], b.cov[1, 1]]])
    d = np.array([float(d_rho), float(d_alpha)])
    try:
        chi2 = float(d @ np.linalg.solve(cov, d))
    except np.linalg.LinAlgError:
        return False
    return chi2 <= p.merge_chi2


def split_and_merge(points: ArrayLike, params: SplitMergeParams | None = None) -> LineObservations:
    """Lines in ``(N, 2)`` points given in scan order (metres, scanner frame; non-finite rows dropped).

    Ranges for the range-dependent thresholds are the points' distances from the origin (the scanner).
    See the module docstring for the algorithm; O(N log N) typical.
    """
    p = params or SplitMergeParams()
    pts = as_points(points)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) < p.min_points:
        return LineObservations.empty()
    # isolated points (farther than the break distance from both neighbours: clutter) go first, so they
    # do not cut walls into pieces
    ranges = np.hypot(pts[:, 0], pts[:, 1])
    near = np.minimum(ranges[:-1], ranges[1:])
    gap = np.hypot(*np.diff(pts, axis=0).T) > p.break_distance_m + p.break_range_ratio * near
    isolated = np.concatenate([[True], gap]) & np.concatenate([gap, [True]])
    pts, ranges = pts[~isolated], ranges[~isolated]
    if len(pts) < p.min_points:
        return LineObservations.empty()
    thr = p.split_threshold_m + p.split_range_ratio * ranges
    step = np.hypot(*np.diff(pts, axis=0).T)
    gap_thr = p.break_distance_m + p.break_range_ratio * np.minimum(ranges[:-1], ranges[1:])
    bounds = np.concatenate([[0], np.flatnonzero(step > gap_thr) + 1, [len(pts)]])
    pieces: list[tuple[int, int]] = []
    for a, b in zip(bounds[:-1].tolist(), bounds[1:].tolist(), strict=True):
        if b - a >= 3:
            _split(pts, thr, a, b - 1, pieces)
    pieces.sort()
    fits = [f for f in (_fit_piece(pts, thr, a, b, p) for a, b in pieces) if f is not None]
    merged = True
    while merged and len(fits) > 1:
        merged = False
        out: list[_Fit] = [fits[0]]
        for f in fits[1:]:
            prev = out[-1]
            if _mergeable(prev, f, p):
                union = _fit_piece(pts, thr, prev.first, f.last, p)
                if union is not None:
                    out[-1] = union
                    merged = True
                    continue
            out.append(f)
        fits = out
    fits = [f for f in fits if _good(f, p)]
    if not fits:
        return LineObservations.empty()
    return LineObservations(
        rho_m=np.array([f.rho for f in fits]),
        alpha_rad=np.array([f.alpha for f in fits]),
        covariance=np.stack([f.cov for f in fits]),
        endpoints=np.stack([f.ends for f in fits]),
        n_points=np.array([f.n for f in fits], dtype=np.intp),
        rms_m=np.array([f.rms for f in fits]),
    )


def extract_lines(scan: Scan, params: SplitMergeParams | None = None) -> LineObservations:
    """:func:`split_and_merge` on the valid returns of ``scan`` (scanner frame, beam order)."""
    points, _ = scan.to_points()
    return split_and_merge(points, params)
