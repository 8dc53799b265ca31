"""The chain covariance of any stretch of keyframes in O(1): prefix sums of its terms.

:func:`shared.slam.closure.chain_covariance` (the reference) sums, over the sequential motions ``m`` from
keyframe ``c`` to ``k``, ``A_m S_m A_m^T`` with ``A_m = [[R_cm, J (r_k - r_m+1)], [0, 0, 1]]`` in ``c``'s
frame: O(k - c) a query, and a loop closure or a retiring keyframe's tie late in a long patrol asks for
the chain back to the first lap (1,400 keyframes after 40 laps of the simulated corridor loop, 70,000
after a day), so each check cost time proportional to the distance driven.

In world coordinates ``A_m = T_c^T B_m`` with ``T_c = diag(R_c, 1)`` and ``B_m = M_m + u e3^T``, where
``M_m = [[R_m, -J p_m+1], [0, 0, 1]]`` depends on motion ``m`` alone and ``u = [J p_k, 0]`` on the chain's
end alone (``J`` the 90 degree rotation, ``p`` positions, ``e3 = [0, 0, 1]``). So

``sum B S B^T = sum M S M^T + (sum M S e3) u^T + u (sum M S e3)^T + u u^T sum S_33``,

and three prefix sums over the motions (a 3x3, a 3-vector and a scalar a keyframe: :func:`extend`)
give the chain of any ``c < k`` (:func:`between`) in O(1). First order, as the reference; equal to it
within rounding (tests: hypothesis against the reference). :class:`ChainSums` holds the sums as the
keyframes come (amortised O(1) a keyframe): a cache the mapper does not save (rebuilt from its rows in
one vectorised pass after a restore).

The functions are pure: arrays in, arrays out.
"""

from __future__ import annotations

import numpy as np

from shared.types import FloatArray

__all__ = ["WIDTH", "ChainSums", "between", "extend"]

#: columns of a prefix row: ``sum M S M^T`` (9, row-major), ``sum M S e3`` (3), ``sum S_33`` (1)
WIDTH = 13


def extend(last: FloatArray, poses: FloatArray, covariances: FloatArray, start: int) -> FloatArray:
    """The prefix rows ``start + 1 .. len(covariances)`` after row ``start`` = ``last`` ``(WIDTH,)`` (row
    ``i``: the sums over motions ``0 .. i - 1``; row 0 is zeros). ``poses`` ``(K, 3)`` are the keyframes'
    world poses (x, y, theta; at least ``len(covariances) + 1`` of them), ``covariances`` ``(K - 1, 9)``
    those of the sequential motions (row-major, in the frame of the motion's start). O(new rows),
    vectorised."""
    end = len(covariances)
    s = np.asarray(covariances[start:end], dtype=np.float64).reshape(-1, 3, 3)
    theta, ahead = poses[start:end, 2], poses[start + 1 : end + 1, :2]
    mm = np.zeros((len(s), 3, 3))
    mm[:, 0, 0], mm[:, 0, 1] = np.cos(theta), -np.sin(theta)
    mm[:, 1, 0], mm[:, 1, 1] = np.sin(theta), np.cos(theta)
    mm[:, 0, 2], mm[:, 1, 2] = ahead[:, 1], -ahead[:, 0]  # -J p_(m+1)
    mm[:, 2, 2] = 1.0
    terms = np.empty((len(s), WIDTH))
    terms[:, :9] = np.einsum("mij,mjk,mlk->mil", mm, s, mm).reshape(-1, 9)
    terms[:, 9:12] = np.einsum("mij,mj->mi", mm, s[:, :, 2])
    terms[:, 12] = s[:, 2, 2]
    out: FloatArray = last + np.cumsum(terms, axis=0)
    return out


def between(prefix: FloatArray, poses: FloatArray, c: int, k: int) -> FloatArray:
    """Covariance ``(3, 3)`` of keyframe ``k`` in keyframe ``c``'s frame by the sequential motions
    between them (``c <= k < len(prefix)``; zeros when ``c >= k``), from the prefix rows and the
    keyframes' world ``poses``. O(1)."""
    if k <= c:
        return np.zeros((3, 3))
    d = prefix[k] - prefix[c]
    q1, q2, q3 = d[:9].reshape(3, 3), d[9:12], d[12]
    x, y = float(poses[k, 0]), float(poses[k, 1])
    u = np.array([-y, x, 0.0])  # J p_k
    world = q1 + np.outer(q2, u) + np.outer(u, q2) + q3 * np.outer(u, u)
    ct, st = np.cos(poses[c, 2]), np.sin(poses[c, 2])
    t = np.array([[ct, -st, 0.0], [st, ct, 0.0], [0.0, 0.0, 1.0]])
    out: FloatArray = t.T @ world @ t
    return 0.5 * (out + out.T)


class ChainSums:
    """The prefix rows of a growing chain, extended on demand (capacity doubling)."""

    def __init__(self) -> None:
        self._rows = np.zeros((64, WIDTH))
        self._n = 1  # row 0: nothing summed

    def covariance(self, poses: FloatArray, covariances: FloatArray, c: int, k: int) -> FloatArray:
        """:func:`between` ``c`` and ``k`` of the chain ``poses`` ``(K, 3)``, ``covariances`` ``(K - 1, 9)``
        (rows only ever appended). Amortised O(1) a new keyframe, O(1) a query."""
        end = len(covariances) + 1
        if end > self._n:
            if end > len(self._rows):
                grown = np.zeros((max(end, 2 * len(self._rows)), WIDTH))
                grown[: self._n] = self._rows[: self._n]
                self._rows = grown
            self._rows[self._n : end] = extend(self._rows[self._n - 1], poses, covariances, self._n - 1)
            self._n = end
        return between(self._rows, poses, c, k)
