"""Scan segmentation by adaptive breakpoint detection and split-and-merge (paper §3.1, eq. 13-16).

1. The valid returns become points ``P_i = r_i (cos phi_i, sin phi_i)`` (eq. 13, :meth:`Scan.to_points`).
   Invalid beams (NaN, inf, outside the range window) are not points at all.
2. Adaptive breakpoint detector (ABD): consecutive valid points ``P_i``, ``P_{i+1}`` stay together when
   ``||P_{i+1} - P_i|| < D_th`` (eq. 14) with ``D_th = r_i sin(dphi) / sin(lambda - dphi) + 3 sigma_r``
   (eq. 15). ``dphi`` is the actual angle between the two beams, so a run of invalid beams between them
   widens the threshold like a coarser scanner would; ``lambda <= dphi`` (a gap so wide that no wall at
   incidence ``lambda`` could bridge it) is always a break. Extension (``max_skip``, default 2; 0 is
   the paper's plain ABD): up to ``max_skip`` returns that break from the piece are dropped as isolated
   outliers (label ``-1``) when the return after them continues it, so a stray return does not cut a wall
   in two.
   The paper segments before removing noise, so without this 5 % clutter returns cut a simulated room
   scan into ~38 pieces instead of ~11.
3. Each breakpoint chunk is split by iterative end-point fit (IEPF): a piece whose farthest point lies more
   than ``D_T`` from its chord is split there. ``D_T`` follows the modified IEPF (MIEPF) rule, eq. 16:
   ``D_T = 3 sigma_r0 + epsilon_a (rho_h - r0)`` clamped to ``[3 sigma_r0, D_T_max]``; we take ``rho_h``
   to be the mean measured range of the piece under test (the paper leaves ``rho_h`` open; the mean range
   is what that piece's range-dependent noise scales with). The paper's split-and-merge [48] then merges
   neighbours whose union passes the same test, and we move each remaining boundary to the best two-line
   least-squares split so corners land where the walls meet (details in
   :mod:`shared.kernels.segmentation._iepf`). Without the merge, IEPF cuts a wall in the middle whenever a
   chunk's chord runs parallel to it.

Pieces with fewer than ``min_points`` points, including chunks that small (isolated returns), get label
``-1``; the others are numbered ``0..S-1`` along the scan.

Complexity: O(n) for the breakpoints (O(n max_skip) with skipping), O(n log n) typical and O(n^2) worst
case for split-and-merge (n valid beams). It all runs in compiled code with explicit stacks (no recursion).
"""

from __future__ import annotations

import math

import numpy as np

from shared.kernels._jit import njit
from shared.kernels.base import SegmentationKernel
from shared.kernels.params import KernelParams, param
from shared.kernels.registry import register
from shared.kernels.results import Segments, freeze
from shared.kernels.segmentation._iepf import split_merge
from shared.types import FloatArray, IntArray, Scan

__all__ = ["AbdIepf", "AbdIepfParams"]


class AbdIepfParams(KernelParams):
    """Parameters of :class:`AbdIepf`; defaults suit the Hokuyo URG-04LX (range noise about 1 cm)."""

    lambda_deg: float = param(
        10.0,
        description="ABD auxiliary angle lambda: the shallowest wall incidence still kept together (eq. 15)",
        unit="deg",
        gt=0.0,
        lt=90.0,
        paper="§3.1 eq. 15",
    )
    sigma_r_m: float = param(
        0.01,
        description="Range noise sigma_r; 3 sigma_r is added to the breakpoint distance D_th (eq. 15)",
        unit="m",
        ge=0.0,
        le=1.0,
        paper="§3.1 eq. 15",
    )
    sigma_r0_m: float = param(
        0.01,
        description="Range noise sigma_r0 at the reference range r0; 3 sigma_r0 is the smallest split "
        "threshold D_T (eq. 16)",
        unit="m",
        gt=0.0,
        le=1.0,
        paper="§3.1 eq. 16",
    )
    epsilon_a: float = param(
        0.025,
        description="MIEPF setting ratio epsilon_a: growth of D_T per metre of mean range beyond r0 "
        "(eq. 16); 0.025 follows the URG-04LX accuracy of 2.5 % of the range beyond 1 m",
        unit="m/m",
        ge=0.0,
        le=1.0,
        paper="§3.1 eq. 16",
    )
    r0_m: float = param(
        1.0,
        description="MIEPF reference range r0 at which D_T = 3 sigma_r0 (eq. 16)",
        unit="m",
        ge=0.0,
        le=100.0,
        paper="§3.1 eq. 16",
    )
    split_max_m: float = param(
        0.10,
        description="Upper bound D_T_max of the IEPF split threshold (eq. 16)",
        unit="m",
        gt=0.0,
        le=10.0,
        paper="§3.1 eq. 16",
    )
    max_skip: int = param(
        2,
        description="Most consecutive returns dropped as isolated outliers (label -1) when the return after "
        "them continues the piece; 0 is the paper's plain ABD",
        ge=0,
        le=100,
        paper="§3.1 (extension)",
    )
    min_points: int = param(
        5,
        description="Pieces with fewer points get label -1 (no segment)",
        ge=1,
        le=100_000,
        paper="§3.1",
    )


@njit
def _joins(
    x: FloatArray, y: FloatArray, r: FloatArray, phi: FloatArray, a: int, b: int, lam: float, sigma_r: float
) -> bool:
    """ABD test (eq. 14-15): does point ``b`` continue the piece ending at point ``a``?"""
    dphi = abs(phi[b] - phi[a])
    if lam <= dphi:
        return False
    d_th = r[a] * math.sin(dphi) / math.sin(lam - dphi) + 3.0 * sigma_r
    return bool(math.hypot(x[b] - x[a], y[b] - y[a]) < d_th)


@njit
def _label_chunk(
    x: FloatArray,
    y: FloatArray,
    r: FloatArray,
    members: IntArray,
    count: int,
    thr: FloatArray,
    min_points: int,
    labels: IntArray,
    next_label: int,
    pieces: IntArray,
    stack: IntArray,
    sums: FloatArray,
) -> int:
    """Split-and-merge one chunk and label its pieces of ``min_points`` or more; return the next label."""
    if count < min_points:
        return next_label  # every piece would be shorter still
    n_pieces = split_merge(x, y, r, members, count, thr, pieces, stack, sums)
    for i in range(n_pieces):
        s = pieces[2 * i]
        e = pieces[2 * i + 1]
        if e - s + 1 >= min_points:
            for j in range(s, e + 1):
                labels[members[j]] = next_label
            next_label += 1
    return next_label


@njit
def _abd_iepf(
    x: FloatArray,
    y: FloatArray,
    r: FloatArray,
    phi: FloatArray,
    lam: float,
    sigma_r: float,
    max_skip: int,
    thr: FloatArray,
    min_points: int,
) -> IntArray:
    """Labels of ``n`` ordered valid returns: ABD chunks (eq. 14-15), each split and merged (eq. 16)."""
    n = x.shape[0]
    labels = np.full(n, -1, dtype=np.intp)
    if n == 0:
        return labels
    members = np.empty(n, dtype=np.intp)
    pieces = np.empty(2 * n, dtype=np.intp)
    stack = np.empty(2 * n + 4, dtype=np.intp)
    sums = np.empty((5, n + 1), dtype=np.float64)
    next_label = 0
    members[0] = 0
    count = 1
    j = 1
    while j < n:
        last = members[count - 1]
        join = -1
        for k in range(j, min(n, j + max_skip + 1)):
            if _joins(x, y, r, phi, last, k, lam, sigma_r):
                join = k
                break
        if join >= 0:  # points j..join-1 (if any) are isolated outliers and keep label -1
            members[count] = join
            count += 1
            j = join + 1
        else:  # breakpoint: finish the chunk, start a new one at j
            next_label = _label_chunk(
                x, y, r, members, count, thr, min_points, labels, next_label, pieces, stack, sums
            )
            members[0] = j
            count = 1
            j += 1
    _label_chunk(x, y, r, members, count, thr, min_points, labels, next_label, pieces, stack, sums)
    return labels


@register
class AbdIepf(SegmentationKernel[AbdIepfParams]):
    """Adaptive breakpoint detector then iterative end-point fit with the MIEPF threshold (paper §3.1)."""

    name = "abd-iepf"
    version = "1.0.0"
    Params = AbdIepfParams

    def apply(self, scan: Scan) -> Segments:
        """Segment the valid returns of ``scan`` into straight pieces. O(n log n) typical, n valid beams."""
        p = self.params
        points, beam_index = scan.to_points()
        ranges = np.ascontiguousarray(scan.ranges_m[beam_index])
        phi = np.ascontiguousarray(scan.angles_rad[beam_index])
        x = np.ascontiguousarray(points[:, 0])
        y = np.ascontiguousarray(points[:, 1])
        thr = np.array([3.0 * p.sigma_r0_m, p.epsilon_a, p.r0_m, p.split_max_m])
        labels = _abd_iepf(
            x, y, ranges, phi, math.radians(p.lambda_deg), p.sigma_r_m, p.max_skip, thr, p.min_points
        )
        beam_index = np.asarray(beam_index, dtype=np.intp)
        freeze(points, beam_index, labels)
        return Segments(points=points, beam_index=beam_index, labels=labels)
