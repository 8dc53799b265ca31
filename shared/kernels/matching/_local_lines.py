"""Local lines (normal and offset) of the reference scan's points, for point-to-line ICP; compiled with numba.

The reference points come in beam order, seen from the scanner at the origin. Two consecutive points lie on
the same surface when their gap is within the adaptive breakpoint distance of Borges & Aldon (the paper's
ABD, §3.1 eq. 15): ``D = r sin(dphi) / sin(lambda - dphi) + 3 sigma``, with ``r`` the smaller of the two
ranges and ``dphi`` the angle between their bearings (measured from the points, so thinned scans work too).
A point's *window* holds its connected scan neighbours on each side while they are within ``radius`` of it,
but always the first connected neighbour on each side (so sparse far returns still get a line) and at most
``max_side`` per side.

The line of a point is the total-least-squares (PCA) line of its window: the normal is the eigenvector of
the smallest eigenvalue of the window's 2x2 scatter and the offset ``c = n . mean``; windows are index
ranges, so their moments come from prefix sums in O(1). A fit is accepted when
``sqrt(lambda_min / lambda_max) <= max_ratio`` (the RMS distance to the line is at most that share of the
RMS spread along it). Of the symmetric window and the two one-sided ones (the point and its left, or its
right, neighbours) the fit with the smallest ratio is used: on a straight wall that is the symmetric one
(twice the spread for the same residual), next to a corner the side on the point's own wall. A point with
fewer than 3 points in every window, or no acceptable fit, gets no line (``valid`` False): it is isolated.

Complexity: O(M * max_side) for the windows, O(M) for the fits.
"""

from __future__ import annotations

import math

import numpy as np

from shared.kernels._jit import njit
from shared.types import BoolArray, FloatArray

__all__: list[str] = []


@njit
def _connected(ref: FloatArray, lambda_rad: float, sigma_m: float) -> BoolArray:
    """``out[i]``: points ``i`` and ``i + 1`` of ``ref`` ``(M, 2)`` lie on one surface (ABD test)."""
    m = ref.shape[0]
    out = np.zeros(max(m - 1, 0), dtype=np.bool_)
    sl = math.sin(lambda_rad)
    cl = math.cos(lambda_rad)
    for i in range(m - 1):
        ax = ref[i, 0]
        ay = ref[i, 1]
        bx = ref[i + 1, 0]
        by = ref[i + 1, 1]
        ra = math.sqrt(ax * ax + ay * ay)
        rb = math.sqrt(bx * bx + by * by)
        gap = math.sqrt((bx - ax) ** 2 + (by - ay) ** 2)
        if ra * rb == 0.0:
            out[i] = gap <= 3.0 * sigma_m
            continue
        # sin and cos of the angle dphi between the bearings; sin(lambda - dphi) from the angle sum rule
        sd = abs(ax * by - ay * bx) / (ra * rb)
        cd = (ax * bx + ay * by) / (ra * rb)
        den = sl * cd - cl * sd
        if den <= 0.0:  # dphi >= lambda: only noise-close points join
            out[i] = gap <= 3.0 * sigma_m
        else:
            out[i] = gap <= min(ra, rb) * sd / den + 3.0 * sigma_m
    return out


@njit
def _fit(cum: FloatArray, lo: int, hi: int) -> tuple[float, float, float, float, float]:
    """PCA line of points ``lo..hi`` (inclusive) from the prefix sums ``cum`` of ``(x, y, xx, yy, xy)``
    (coordinates relative to ``cum``'s origin): ``(nx, ny, c, ratio, lambda_max)``; ratio inf when
    degenerate."""
    n = hi - lo + 1
    sx = cum[hi + 1, 0] - cum[lo, 0]
    sy = cum[hi + 1, 1] - cum[lo, 1]
    mx = sx / n
    my = sy / n
    sxx = max(cum[hi + 1, 2] - cum[lo, 2] - sx * mx, 0.0)
    syy = max(cum[hi + 1, 3] - cum[lo, 3] - sy * my, 0.0)
    sxy = cum[hi + 1, 4] - cum[lo, 4] - sx * my
    half = 0.5 * (sxx + syy)
    root = math.sqrt(0.25 * (sxx - syy) ** 2 + sxy * sxy)
    lmax = half + root
    lmin = max(half - root, 0.0)
    if not lmax > 0.0:
        return 0.0, 0.0, 0.0, math.inf, 0.0
    # eigenvector of lmin: the better conditioned of the two rows of (S - lmin I)
    if sxx >= syy:
        nx = sxy
        ny = lmin - sxx
    else:
        nx = lmin - syy
        ny = sxy
    norm = math.sqrt(nx * nx + ny * ny)
    if norm == 0.0:  # isotropic scatter: no line
        return 0.0, 0.0, 0.0, math.inf, 0.0
    nx /= norm
    ny /= norm
    return nx, ny, nx * mx + ny * my, math.sqrt(lmin / lmax), lmax


@njit
def _local_lines(
    ref: FloatArray,
    radius_m: float,
    max_side: int,
    lambda_rad: float,
    sigma_m: float,
    max_ratio: float,
    max_direction_sd_rad: float = math.inf,
    noise_floor_m: float = 0.0,
) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Line of every point of ``ref`` ``(M, 2)`` (finite, beam order): ``(normals (M, 2), offsets (M,),
    valid (M,))``; the line of point ``j`` is ``normals[j] . p = offsets[j]``.

    With a finite ``max_direction_sd_rad`` a fit must also know its direction: its standard deviation
    ``sqrt(s^2 / lambda_max)``, ``s^2`` the residual variance ``lambda_min / (n - 2)`` but at least
    ``noise_floor_m^2`` (a few points can line up by chance), at most that. A short window of dense
    returns whose noise exceeds their spacing (a wall beside the scanner, cut short by clutter returns)
    otherwise gets a line at any angle, and a match reads information along the wall from it."""
    m = ref.shape[0]
    normals = np.zeros((m, 2), dtype=np.float64)
    offsets = np.zeros(m, dtype=np.float64)
    valid = np.zeros(m, dtype=np.bool_)
    conn = _connected(ref, lambda_rad, sigma_m)
    # prefix sums of the moments, about the centroid for precision
    ox = 0.0
    oy = 0.0
    for i in range(m):
        ox += ref[i, 0]
        oy += ref[i, 1]
    ox /= max(m, 1)
    oy /= max(m, 1)
    cum = np.zeros((m + 1, 5), dtype=np.float64)
    for i in range(m):
        x = ref[i, 0] - ox
        y = ref[i, 1] - oy
        cum[i + 1, 0] = cum[i, 0] + x
        cum[i + 1, 1] = cum[i, 1] + y
        cum[i + 1, 2] = cum[i, 2] + x * x
        cum[i + 1, 3] = cum[i, 3] + y * y
        cum[i + 1, 4] = cum[i, 4] + x * y
    r2 = radius_m * radius_m
    for i in range(m):
        lo = i
        while lo > 0 and i - lo < max_side and conn[lo - 1]:
            dx = ref[lo - 1, 0] - ref[i, 0]
            dy = ref[lo - 1, 1] - ref[i, 1]
            if lo < i and dx * dx + dy * dy > r2:
                break
            lo -= 1
        hi = i
        while hi < m - 1 and hi - i < max_side and conn[hi]:
            dx = ref[hi + 1, 0] - ref[i, 0]
            dy = ref[hi + 1, 1] - ref[i, 1]
            if hi > i and dx * dx + dy * dy > r2:
                break
            hi += 1
        best = math.inf
        bnx = 0.0
        bny = 0.0
        bc = 0.0
        blmax = 0.0
        bn = 0
        if hi - lo >= 2:
            bnx, bny, bc, best, blmax = _fit(cum, lo, hi)
            bn = hi - lo + 1
        # the one-sided fits win only where they are straighter (a corner); on a straight noisy wall the
        # symmetric fit spreads twice as far for the same residual, so its ratio is about half theirs
        if best > 0.0:
            for a, b in ((lo, i), (i, hi)):
                if b - a >= 2:
                    nx, ny, c, ratio, lmax = _fit(cum, a, b)
                    if ratio < best:
                        bnx, bny, bc, best, blmax, bn = nx, ny, c, ratio, lmax, b - a + 1
        if best <= max_ratio and max_direction_sd_rad < math.inf:
            # residual variance lambda_min / (n - 2), lambda_min = ratio^2 lambda_max, floored
            resid = max(best * best * blmax / max(bn - 2, 1), noise_floor_m * noise_floor_m)
            if not blmax > 0.0 or resid > max_direction_sd_rad * max_direction_sd_rad * blmax:
                best = math.inf
        if best <= max_ratio:
            normals[i, 0] = bnx
            normals[i, 1] = bny
            offsets[i] = bc + bnx * ox + bny * oy  # back from the centroid origin
            valid[i] = True
    return normals, offsets, valid
