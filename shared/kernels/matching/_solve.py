"""The two alignment steps of point-to-line ICP over given pairs, compiled with numba.

* :func:`_point_align`: closed-form point-to-point rigid alignment (2D Kabsch) of the selected pairs,
  from the original current points, so the result is an absolute pose.
* :func:`_line_step`: one Gauss-Newton step of the point-to-line objective, solved through the 3x3
  normal equations over the eigen-directions that the pairs constrain (the rest get no update).

Both are O(N) in the number of current points.
"""

from __future__ import annotations

import math

import numpy as np

from shared.kernels._jit import njit
from shared.types import FloatArray, IntArray

__all__: list[str] = []


@njit
def _point_align(
    current: FloatArray, reference: FloatArray, pair: IntArray, res: FloatArray, cut: float
) -> tuple[float, float, float]:
    """Pose ``(x, y, theta)`` that best maps ``current[i]`` onto ``reference[pair[i]]`` in least squares,
    over the pairs with ``pair[i] >= 0`` and ``res[i] <= cut`` (at least 3 of them)."""
    n = 0
    pxm = 0.0
    pym = 0.0
    qxm = 0.0
    qym = 0.0
    for i in range(current.shape[0]):
        j = pair[i]
        if j >= 0 and res[i] <= cut:
            n += 1
            pxm += current[i, 0]
            pym += current[i, 1]
            qxm += reference[j, 0]
            qym += reference[j, 1]
    pxm /= n
    pym /= n
    qxm /= n
    qym /= n
    dot = 0.0
    cross = 0.0
    for i in range(current.shape[0]):
        j = pair[i]
        if j >= 0 and res[i] <= cut:
            px = current[i, 0] - pxm
            py = current[i, 1] - pym
            qx = reference[j, 0] - qxm
            qy = reference[j, 1] - qym
            dot += px * qx + py * qy
            cross += px * qy - py * qx
    theta = math.atan2(cross, dot)
    c = math.cos(theta)
    s = math.sin(theta)
    return qxm - (c * pxm - s * pym), qym - (s * pxm + c * pym), theta


@njit
def _line_step(
    px: FloatArray,
    py: FloatArray,
    normals: FloatArray,
    pair: IntArray,
    res: FloatArray,
    cut: float,
    scale: float,
    degeneracy: float,
) -> tuple[float, float, float]:
    """Step ``(dx, dy, dtheta)`` (applied on the left: rotate the mapped points about the origin, then
    shift) that minimises ``sum (res_i + n_x dx + n_y dy + (n x p_i) dtheta)^2`` over the pairs with
    ``pair[i] >= 0`` and ``|res[i]| <= cut``; ``p_i = (px[i], py[i])`` are the mapped current points.

    Solved in the unknowns ``(dx, dy, scale * dtheta)`` (``scale`` in metres, so all three are lengths)
    through the eigen-decomposition of the 3x3 normal matrix: directions whose eigenvalue is at most
    ``degeneracy`` times the largest are left at zero.
    """
    h00 = h01 = h02 = h11 = h12 = h22 = 0.0
    g0 = g1 = g2 = 0.0
    for i in range(px.shape[0]):
        j = pair[i]
        if j >= 0 and abs(res[i]) <= cut:
            j0 = normals[j, 0]
            j1 = normals[j, 1]
            j2 = (j1 * px[i] - j0 * py[i]) / scale
            r = res[i]
            h00 += j0 * j0
            h01 += j0 * j1
            h02 += j0 * j2
            h11 += j1 * j1
            h12 += j1 * j2
            h22 += j2 * j2
            g0 += j0 * r
            g1 += j1 * r
            g2 += j2 * r
    hm = np.array([[h00, h01, h02], [h01, h11, h12], [h02, h12, h22]])
    w, v = np.linalg.eigh(hm)
    top = w[2]
    d0 = 0.0
    d1 = 0.0
    d2 = 0.0
    if not top > 0.0:
        return d0, d1, d2
    for k in range(3):
        if w[k] > degeneracy * top:
            a = -(v[0, k] * g0 + v[1, k] * g1 + v[2, k] * g2) / w[k]
            d0 += a * v[0, k]
            d1 += a * v[1, k]
            d2 += a * v[2, k]
    return d0, d1, d2 / scale
