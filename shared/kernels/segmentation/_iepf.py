"""Split-and-merge of one breakpoint chunk: IEPF with the MIEPF threshold (paper §3.1, eq. 16), compiled.

A chunk is a run of points in scan order, given as indices ``members[:count]`` into the scan's point arrays.
Positions ``s..e`` below index ``members``. Four passes, all O(count) memory, no recursion:

1. **Split** (iterative end-point fit, explicit stack): a piece whose farthest point lies more than ``D_T``
   from the chord between its end points is split there, the farthest point going to the first half;
   repeated until no piece fails. Halves come out in scan order.
2. **Merge**: neighbours whose union passes the same test are joined, left to right (the "merge" of the
   paper's split-and-merge [48]). This undoes splits that IEPF makes far from any corner, e.g. in the middle
   of a wall when the chunk's chord runs parallel to it.
3. **Refine**: for two neighbours that must stay apart, the boundary is moved to where two least-squares
   lines fit the union best (minimum summed squared orthogonal residuals, each side >= 2 points, O(1) per
   candidate from prefix sums). IEPF alone puts a corner up to a few points off when noise tilts a chord
   that meets the corner at a shallow angle; this makes the corner land where the two walls meet.
4. **Merge** again (a refined boundary can leave a few points that belong with the next piece).

``D_T = 3 sigma_r0 + epsilon_a (rho_h - r0)`` clamped to ``[3 sigma_r0, D_T_max]`` (upper bound wins),
with ``rho_h`` the mean measured range of the piece under test.

Complexity: split O(n log n) typical, O(n^2) worst case; merge O(n) per pass plus the tested unions;
refine O(n).
"""

from __future__ import annotations

import math

from shared.kernels._jit import njit
from shared.types import FloatArray, IntArray

__all__ = ["split_merge"]


@njit
def _farthest(x: FloatArray, y: FloatArray, members: IntArray, s: int, e: int) -> tuple[int, float]:
    """Position ``k`` in ``s+1..e-1`` of the point farthest from the chord ``s``-``e``, and its distance.

    ``(-1, 0.0)`` without interior points. A closed chord (equal end points) uses the distance to the end.
    """
    xs = x[members[s]]
    ys = y[members[s]]
    ux = x[members[e]] - xs
    uy = y[members[e]] - ys
    norm = math.hypot(ux, uy)
    k = -1
    d_max = 0.0
    if norm > 0.0:
        for j in range(s + 1, e):
            m = members[j]
            d = abs(ux * (y[m] - ys) - uy * (x[m] - xs))  # |cross(P_e - P_s, P_j - P_s)|
            if d > d_max:
                d_max = d
                k = j
        return k, d_max / norm
    for j in range(s + 1, e):
        m = members[j]
        d = math.hypot(x[m] - xs, y[m] - ys)
        if d > d_max:
            d_max = d
            k = j
    return k, d_max


@njit
def _straight(
    x: FloatArray, y: FloatArray, r: FloatArray, members: IntArray, s: int, e: int, thr: FloatArray
) -> tuple[bool, int]:
    """IEPF test of piece ``s..e``: ``(True, -1)`` if no point is farther than ``D_T`` (eq. 16) from the
    chord, else ``(False, k)`` with ``k`` the farthest point. ``thr = (3 sigma_r0, epsilon_a, r0, D_T_max)``.
    """
    mean_r = 0.0
    for j in range(s, e + 1):
        mean_r += r[members[j]]
    mean_r /= e - s + 1
    d_t = min(max(thr[0] + thr[1] * (mean_r - thr[2]), thr[0]), thr[3])
    k, d_max = _farthest(x, y, members, s, e)
    if k >= 0 and d_max > d_t:
        return False, k
    return True, -1


@njit
def _merge(
    x: FloatArray,
    y: FloatArray,
    r: FloatArray,
    members: IntArray,
    pieces: IntArray,
    n_pieces: int,
    thr: FloatArray,
) -> int:
    """Join neighbouring pieces left to right while their union is straight; returns the new count."""
    out = 0
    s = pieces[0]
    e = pieces[1]
    for i in range(1, n_pieces + 1):
        if i < n_pieces:
            e_next = pieces[2 * i + 1]
            ok, _ = _straight(x, y, r, members, s, e_next, thr)
            if ok:
                e = e_next
                continue
        pieces[2 * out] = s
        pieces[2 * out + 1] = e
        out += 1
        if i < n_pieces:
            s = pieces[2 * i]
            e = pieces[2 * i + 1]
    return out


@njit
def _sse(sums: FloatArray, a: int, b: int) -> float:
    """Summed squared orthogonal residuals of the least-squares line through positions ``a..b``."""
    n = b - a + 1
    sx = sums[0, b + 1] - sums[0, a]
    sy = sums[1, b + 1] - sums[1, a]
    cxx = sums[2, b + 1] - sums[2, a] - sx * sx / n
    cyy = sums[3, b + 1] - sums[3, a] - sy * sy / n
    cxy = sums[4, b + 1] - sums[4, a] - sx * sy / n
    half = 0.5 * (cxx - cyy)
    sse: float = max(0.5 * (cxx + cyy) - math.sqrt(half * half + cxy * cxy), 0.0)
    return sse


@njit
def _refine(
    x: FloatArray,
    y: FloatArray,
    r: FloatArray,
    members: IntArray,
    count: int,
    pieces: IntArray,
    n_pieces: int,
    thr: FloatArray,
    sums: FloatArray,
) -> None:
    """Move each boundary between two pieces that stay apart to the best two-line split of their union."""
    x0 = x[members[0]]
    y0 = y[members[0]]
    sums[:, 0] = 0.0
    for j in range(count):
        px = x[members[j]] - x0  # relative to the chunk's first point, against cancellation
        py = y[members[j]] - y0
        sums[0, j + 1] = sums[0, j] + px
        sums[1, j + 1] = sums[1, j] + py
        sums[2, j + 1] = sums[2, j] + px * px
        sums[3, j + 1] = sums[3, j] + py * py
        sums[4, j + 1] = sums[4, j] + px * py
    for i in range(n_pieces - 1):
        s = pieces[2 * i]
        e = pieces[2 * i + 3]
        if e - s + 1 < 4:
            continue
        ok, _ = _straight(x, y, r, members, s, e, thr)
        if ok:
            continue  # the second merge joins them
        best = math.inf
        best_b = pieces[2 * i + 1]
        for b in range(s + 1, e - 1):
            cost = _sse(sums, s, b) + _sse(sums, b + 1, e)
            if cost < best:
                best = cost
                best_b = b
        pieces[2 * i + 1] = best_b
        pieces[2 * i + 2] = best_b + 1


@njit
def split_merge(
    x: FloatArray,
    y: FloatArray,
    r: FloatArray,
    members: IntArray,
    count: int,
    thr: FloatArray,
    pieces: IntArray,
    stack: IntArray,
    sums: FloatArray,
) -> int:
    """Split, merge, refine and merge the chunk ``members[:count]`` (``count >= 1``).

    Writes the pieces as position pairs ``pieces[2i], pieces[2i+1]`` (in scan order, covering the chunk)
    and returns their number. Scratch: ``stack`` ``(2 count + 4,)``, ``sums`` ``(5, count + 1)``.
    """
    n_pieces = 0
    stack[0] = 0
    stack[1] = count - 1
    top = 1
    while top > 0:
        top -= 1
        s = stack[2 * top]
        e = stack[2 * top + 1]
        ok, k = _straight(x, y, r, members, s, e, thr)
        if ok:
            pieces[2 * n_pieces] = s
            pieces[2 * n_pieces + 1] = e
            n_pieces += 1
        else:  # push the right half first so the left half is finished first
            stack[2 * top] = k + 1
            stack[2 * top + 1] = e
            stack[2 * top + 2] = s
            stack[2 * top + 3] = k
            top += 2
    n_pieces = _merge(x, y, r, members, pieces, n_pieces, thr)
    if n_pieces > 1:
        _refine(x, y, r, members, count, pieces, n_pieces, thr, sums)
        n_pieces = _merge(x, y, r, members, pieces, n_pieces, thr)
    return n_pieces
