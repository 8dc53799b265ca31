"""Data association of the line-segment EKF-SLAM baseline (:mod:`shared.baselines.ekf_lines`, paper §6.3):
which observed line is which landmark.

Vectorised over the M observations x L landmarks: the innovation ``v = z - h(x)`` with the angle wrapped
and the rho sign flip handled (:func:`~shared.baselines.line_model.line_difference`), its covariance
``S = H P H^T + R`` (the rho row of ``h`` and ``H`` scaled by the flip's sign) and the squared Mahalanobis
distance ``v^T S^-1 v`` (dimensionless); pairs within ``gate_chi2`` are assigned greedily, nearest first,
each landmark and each observation at most once. Units: m and rad. O(M L + L).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shared.baselines.line_model import line_difference, predict_lines
from shared.types import FloatArray, IntArray, Pose2D

__all__ = ["Association", "associate", "inv2"]


@dataclass(frozen=True, slots=True)
class Association:
    """The matched ``pairs`` ``(observation, landmark)`` in the order assigned, with their innovations
    ``v`` ``(k, 2)`` and Jacobians ``Hr`` ``(k, 2, 3)`` / ``Hl`` ``(k, 2, 2)`` (sign flip applied; empty
    arrays when ``k = 0``), and per observation the nearest landmark ``best_j`` ``(M,)`` (-1: none) at
    squared Mahalanobis distance ``best`` ``(M,)`` (inf: none)."""

    pairs: list[tuple[int, int]]
    v: FloatArray
    Hr: FloatArray
    Hl: FloatArray
    best: FloatArray
    best_j: IntArray


def inv2(S: FloatArray) -> FloatArray:
    """Inverse of a stack of 2x2 matrices ``(..., 2, 2)`` (analytic). O(stack)."""
    a, b, c, d = S[..., 0, 0], S[..., 0, 1], S[..., 1, 0], S[..., 1, 1]
    det = a * d - b * c
    det = np.where(np.abs(det) > 1e-300, det, 1e-300)
    out = np.empty_like(S)
    out[..., 0, 0] = d / det
    out[..., 0, 1] = -b / det
    out[..., 1, 0] = -c / det
    out[..., 1, 1] = a / det
    return out


def associate(
    x: FloatArray, P: FloatArray, laser_offset: Pose2D, z: FloatArray, R: FloatArray, gate_chi2: float
) -> Association:
    """Match the observations ``z`` ``(M, 2)`` ``[rho_m, alpha_rad]`` (scanner frame) with covariances
    ``R`` ``(M, 2, 2)`` to the landmarks of the state ``x`` ``(3 + 2 L,)`` with covariance ``P`` (module
    docstring). O(M L + L)."""
    m = len(z)
    L = (x.size - 3) // 2
    best = np.full(m, np.inf)
    best_j = np.full(m, -1, dtype=np.intp)
    pairs: list[tuple[int, int]] = []
    v_sel: list[FloatArray] = []
    Hr_sel: list[FloatArray] = []
    Hl_sel: list[FloatArray] = []
    if L:
        lm = x[3:].reshape(L, 2)
        h, H_r, H_l = predict_lines(x[:3], laser_offset, lm[:, 0], lm[:, 1])
        idx = 3 + 2 * np.arange(L)
        P_rr = P[:3, :3]
        P_rl = P[:3, 3:].reshape(3, L, 2).transpose(1, 0, 2)  # (L, 3, 2)
        P_ll = np.empty((L, 2, 2))
        P_ll[:, 0, 0] = P[idx, idx]
        P_ll[:, 0, 1] = P[idx, idx + 1]
        P_ll[:, 1, 0] = P[idx + 1, idx]
        P_ll[:, 1, 1] = P[idx + 1, idx + 1]
        cross = H_r @ P_rl @ H_l.transpose(0, 2, 1)
        S_base = H_r @ P_rr @ H_r.transpose(0, 2, 1) + cross + cross.transpose(0, 2, 1)
        S_base += H_l @ P_ll @ H_l.transpose(0, 2, 1)
        # innovations (M, L) with the sign flip: the rho row of h and H scales by `sign`
        d_rho, d_alpha, sign = line_difference(z[:, 0:1], z[:, 1:2], h[None, :, 0], h[None, :, 1])
        S = np.broadcast_to(S_base, (m, L, 2, 2)).copy()
        S[..., 0, 1] *= sign
        S[..., 1, 0] *= sign
        S += R[:, None, :, :]
        Si = inv2(S)
        d2 = (
            d_rho * d_rho * Si[..., 0, 0]
            + 2.0 * d_rho * d_alpha * Si[..., 0, 1]
            + d_alpha * d_alpha * Si[..., 1, 1]
        )
        best_j = np.argmin(d2, axis=1).astype(np.intp)
        best = d2[np.arange(m), best_j]
        cand_i, cand_j = np.nonzero(d2 <= gate_chi2)
        order = np.argsort(d2[cand_i, cand_j], kind="stable")
        used_obs: set[int] = set()
        used_lm: set[int] = set()
        for k in order.tolist():
            i, j = int(cand_i[k]), int(cand_j[k])
            if i in used_obs or j in used_lm:
                continue
            used_obs.add(i)
            used_lm.add(j)
            pairs.append((i, j))
            v_sel.append(np.array([d_rho[i, j], d_alpha[i, j]]))
            scale = np.array([[sign[i, j]], [1.0]])
            Hr_sel.append(H_r[j] * scale)
            Hl_sel.append(H_l[j] * scale)
    if not pairs:
        return Association(pairs, np.zeros((0, 2)), np.zeros((0, 2, 3)), np.zeros((0, 2, 2)), best, best_j)
    return Association(pairs, np.stack(v_sel), np.stack(Hr_sel), np.stack(Hl_sel), best, best_j)
