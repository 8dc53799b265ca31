"""The loop search's window from what the graph already knows of the relative pose.

A loop search (:func:`shared.slam.closure.verify`) looks for keyframe ``k`` in candidate ``c``'s submap
within +-``window_m``, +-``window_rad`` of the graph's guess: the drift a loop may have gathered since the
robot was last there. Once a closure has tied the robot's stretch to that place (keyframe ``j`` a few
keyframes before ``k`` matched keyframe ``c'`` near ``c``), the relative pose of ``k`` in ``c``'s frame is
known far better than that: along the path ``c -> c' -> j -> k`` (the sequential chain from ``c`` to
``c'``, the closure, the chain from ``j`` to ``k``) its first-order covariance is at most
:func:`path_covariance`. :func:`search_window` sizes the window to :data:`WINDOW_SIGMAS` standard deviations
of the tightest such path, no smaller than :data:`MIN_WINDOW_M` / :data:`MIN_WINDOW_RAD` and no larger than
the operator's window. Along a corridor a closure holds the along-track place at the graph's estimate with
no information (:func:`shared.slam.edges.hold_unseen`), so its path's covariance is huge that way and the
window stays whole: the narrow window only ever serves scans that fixed the place in every direction.

Cost: a coarse search's work grows with the window's area times its rotations; a 0.5 m, 0.1 rad window is
about 1/90 of the default 2.5 m, 0.35 rad one. Pure: arrays in, two numbers out. O(P (k - j + |c - c'|))
for P tying closures.
"""

from __future__ import annotations

import math

import numpy as np

from shared.slam.closure import chain_covariance
from shared.slam.riders import inverse_jacobian
from shared.slam.settings import LoopClosureSettings
from shared.types import FloatArray, Pose2D

__all__ = [
    "MIN_WINDOW_M",
    "MIN_WINDOW_RAD",
    "TIE_KEYFRAMES",
    "WINDOW_SIGMAS",
    "inverse_covariance",
    "path_covariance",
    "search_window",
]

#: the window's half-width in standard deviations of the relative pose
WINDOW_SIGMAS = 4.0
#: the narrowest window (what the first-order covariances may miss: a closure a little off, the chain's
#: model): half-widths in m and rad
MIN_WINDOW_M = 0.5
MIN_WINDOW_RAD = 0.1
#: closures of the keyframes at most this many before ``k`` (and at most this many from ``c``) tie it
TIE_KEYFRAMES = 6


def inverse_covariance(motion: Pose2D, cov: FloatArray) -> FloatArray:
    """Covariance ``(3, 3)`` of ``motion^-1`` given that of ``motion`` (additive noise on ``(x, y,
    theta)``, as :func:`~shared.slam.closure.chain_covariance` takes it), first order
    (:func:`shared.slam.riders.inverse_jacobian`). O(1)."""
    jac = inverse_jacobian(np.array(motion.as_tuple()))
    out: FloatArray = jac @ cov @ jac.T
    return out


def _chain(poses: FloatArray, seq_cov: FloatArray, a: int, b: int) -> FloatArray:
    """Covariance of keyframe ``b`` in ``a``'s frame by the sequential chain (either order)."""
    lo, hi = min(a, b), max(a, b)
    if lo == hi:
        return np.zeros((3, 3))
    chain = [Pose2D(*row) for row in poses[lo : hi + 1].tolist()]
    cov = chain_covariance(chain, seq_cov[lo:hi].reshape(-1, 3, 3))
    return cov if a <= b else inverse_covariance(chain[0].between(chain[-1]), cov)


def path_covariance(
    poses: FloatArray,
    seq_cov: FloatArray,
    c: int,
    k: int,
    tie: tuple[int, int],
    tie_cov: FloatArray,
) -> FloatArray:
    """Covariance ``(3, 3)`` of keyframe ``k`` in keyframe ``c``'s frame along ``c -> c' -> j -> k`` for
    the closure ``tie = (j, c')`` (keyframe ``j`` seen in ``c'``'s frame with covariance ``tie_cov``):
    ``poses`` ``(K, 3)`` are the keyframes' poses (their lever arms), ``seq_cov`` ``(K - 1, 9)`` the
    sequential edges' covariances (row-major). First order, the three parts independent
    (:func:`~shared.slam.closure.chain_covariance`). O(|c - c'| + |k - j|)."""
    j, cp = tie
    at = [Pose2D(*poses[i].tolist()) for i in (c, cp, j, k)]
    parts = np.stack([_chain(poses, seq_cov, c, cp), tie_cov, _chain(poses, seq_cov, j, k)])
    return chain_covariance(at, parts)


def search_window(
    poses: FloatArray,
    seq_cov: FloatArray,
    c: int,
    k: int,
    ties: FloatArray,
    tie_covs: FloatArray,
    settings: LoopClosureSettings,
) -> tuple[float, float]:
    """Half-widths ``(m, rad)`` of the search for keyframe ``k`` in candidate ``c``'s submap (module
    docstring): ``ties`` ``(P, 2)`` are accepted closures as ``(current, candidate)`` keyframes and
    ``tie_covs`` ``(P, 9)`` their covariances; those with ``current`` in ``[k - TIE_KEYFRAMES, k)`` and
    ``candidate`` within ``TIE_KEYFRAMES`` of ``c`` bound the window; without one it is the settings'.
    O(P) to pick them plus :func:`path_covariance` each."""
    full = (settings.window_m, settings.window_rad)
    if not len(ties):
        return full
    cur, cand = ties[:, 0], ties[:, 1]
    use = np.flatnonzero((cur < k) & (cur >= k - TIE_KEYFRAMES) & (np.abs(cand - c) <= TIE_KEYFRAMES))
    best_m, best_rad = full
    for i in use.tolist():
        cov = path_covariance(
            poses, seq_cov, c, k, (int(cur[i]), int(cand[i])), tie_covs[i].reshape(3, 3)
        )
        var_xy = float(np.linalg.eigvalsh(0.5 * (cov[:2, :2] + cov[:2, :2].T))[-1])
        if not (math.isfinite(var_xy) and math.isfinite(cov[2, 2])):
            continue
        half_m = max(WINDOW_SIGMAS * math.sqrt(max(var_xy, 0.0)), MIN_WINDOW_M)
        half_rad = max(WINDOW_SIGMAS * math.sqrt(max(float(cov[2, 2]), 0.0)), MIN_WINDOW_RAD)
        if half_m < best_m:
            best_m, best_rad = half_m, half_rad
    return (min(best_m, full[0]), min(best_rad, full[1]))
