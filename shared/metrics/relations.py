"""Relation-based trajectory error (Kümmerle et al. 2009, "On measuring the accuracy of SLAM algorithms").

For every ground-truth relation ``rel_gt`` between times ``t1`` and ``t2``, the estimate's relation is
``rel_est = pose(t1)^-1 * pose(t2)`` and the error ``err = rel_gt^-1 * rel_est``; the metric is the mean and
standard deviation of ``|translation(err)|`` (m) and ``|yaw(err)|`` (deg) over the relations (docs/design.md
§5, ``data/README.md`` "Benchmark metric"). Squared variants are reported too, as the benchmark does.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, fields

import numpy as np
from numpy.typing import ArrayLike

from shared.metrics.errors import MetricError, MetricInputError
from shared.metrics.relations_io import Relations
from shared.types import BoolArray, FloatArray, IntArray

__all__ = ["RelationError", "match_stamps", "relation_error"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True, eq=False)
class RelationError:
    """Relation errors of one trajectory against one relations set.

    Statistics are over the ``n_used`` relations whose two stamps were both found in the trajectory;
    ``n_unmatched = n_relations - n_used``. Standard deviations are population ones (ddof = 0).
    ``translation_m`` and ``rotation_deg`` hold the per-relation errors (NaN where unmatched).
    """

    n_relations: int
    n_used: int
    n_unmatched: int
    trans_mean_m: float
    trans_std_m: float
    trans_max_m: float
    rot_mean_deg: float
    rot_std_deg: float
    rot_max_deg: float
    trans_sq_mean_m2: float
    trans_sq_std_m2: float
    rot_sq_mean_deg2: float
    rot_sq_std_deg2: float
    translation_m: FloatArray
    rotation_deg: FloatArray

    def summary(self) -> dict[str, float | int]:
        """The scalar fields as a plain dict (for JSON and tables)."""
        skip = ("translation_m", "rotation_deg")
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name not in skip}


def match_stamps(stamps_s: FloatArray, query_s: FloatArray, tolerance_s: float) -> IntArray:
    """Index into ``stamps_s`` of the stamp nearest to each query, or -1 if none is within ``tolerance_s``.

    ``stamps_s`` need not be sorted. O((T + Q) log T).
    """
    if len(stamps_s) == 0:
        return np.full(len(query_s), -1, dtype=np.intp)
    order = np.argsort(stamps_s, kind="stable")
    sorted_s = stamps_s[order]
    hi = np.clip(np.searchsorted(sorted_s, query_s), 1, len(sorted_s) - 1) if len(sorted_s) > 1 else None
    if hi is None:
        pick = np.zeros(len(query_s), dtype=np.intp)
    else:
        lo = hi - 1
        pick = np.where(np.abs(sorted_s[lo] - query_s) <= np.abs(sorted_s[hi] - query_s), lo, hi)
    ok = np.abs(sorted_s[pick] - query_s) <= tolerance_s
    return np.where(ok, order[pick], -1).astype(np.intp)


def _wrap(angle: FloatArray) -> FloatArray:
    return np.asarray(np.remainder(angle + np.pi, 2.0 * np.pi) - np.pi)


def _validate(stamps_s: ArrayLike, poses: ArrayLike) -> tuple[FloatArray, FloatArray]:
    t = np.asarray(stamps_s, dtype=np.float64)
    p = np.asarray(poses, dtype=np.float64)
    if t.ndim != 1:
        raise MetricInputError(f"stamps has shape {t.shape}: expected (T,) seconds")
    if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] != t.shape[0]:
        raise MetricInputError(
            f"poses has shape {p.shape}: expected ({t.shape[0]}, 3) rows [x_m, y_m, theta_rad], one per stamp"
        )
    for name, arr in (("stamps", t), ("poses", p)):
        if not np.all(np.isfinite(arr)):
            bad = int(np.flatnonzero(~np.isfinite(arr.reshape(len(arr), -1)).all(axis=1))[0])
            raise MetricInputError(f"{name}[{bad}] = {arr[bad].tolist()} is not finite")
    return t, p


def relation_error(
    stamps_s: ArrayLike,
    poses: ArrayLike,
    relations: Relations,
    *,
    stamp_tolerance_s: float = 1e-3,
) -> RelationError:
    """Kümmerle et al. relation error of the trajectory ``poses`` ``(T, 3)`` taken at ``stamps_s`` ``(T,)``.

    Each relation time is matched to the nearest trajectory stamp within ``stamp_tolerance_s`` (the MIT CSAIL
    relations print 5 decimals where the log has 6). Relations with an unmatched stamp are counted in
    ``n_unmatched`` and logged; if none matches, :class:`MetricError` is raised. Vectorised, O((T + N) log T).
    """
    if not (math.isfinite(stamp_tolerance_s) and stamp_tolerance_s >= 0.0):
        raise MetricInputError(f"stamp_tolerance_s = {stamp_tolerance_s!r}: expected seconds >= 0")
    t, p = _validate(stamps_s, poses)
    n = len(relations)
    if n == 0:
        raise MetricError(f"{relations.source}: no relations to evaluate")
    i1 = match_stamps(t, relations.t1_s, stamp_tolerance_s)
    i2 = match_stamps(t, relations.t2_s, stamp_tolerance_s)
    used: BoolArray = (i1 >= 0) & (i2 >= 0)
    n_used = int(used.sum())
    if n_used == 0:
        span = f"[{t.min():.6f}, {t.max():.6f}] s" if len(t) else "empty"
        raise MetricError(
            f"none of the {n} relations in {relations.source} has both stamps in the trajectory "
            f"(stamps {span}, "
            f"relations [{relations.t1_s.min():.6f}, {relations.t2_s.max():.6f}] s, "
            f"tolerance {stamp_tolerance_s} s)"
        )
    if n_used < n:
        log.info("%d of %d relations have a stamp not in the trajectory", n - n_used, n)
    a, b = p[i1[used]], p[i2[used]]
    # rel_est = pose(t1)^-1 * pose(t2)
    dx, dy = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
    ca, sa = np.cos(a[:, 2]), np.sin(a[:, 2])
    ex, ey, eth = ca * dx + sa * dy, -sa * dx + ca * dy, b[:, 2] - a[:, 2]
    # err = rel_gt^-1 * rel_est
    gx, gy, gth = relations.x_m[used], relations.y_m[used], relations.yaw_rad[used]
    cg, sg = np.cos(gth), np.sin(gth)
    rx, ry = ex - gx, ey - gy
    err_x, err_y = cg * rx + sg * ry, -sg * rx + cg * ry
    trans = np.hypot(err_x, err_y)
    rot = np.degrees(np.abs(_wrap(eth - gth)))
    translation = np.full(n, np.nan)
    rotation = np.full(n, np.nan)
    translation[used] = trans
    rotation[used] = rot
    translation.setflags(write=False)
    rotation.setflags(write=False)
    return RelationError(
        n_relations=n,
        n_used=n_used,
        n_unmatched=n - n_used,
        trans_mean_m=float(trans.mean()),
        trans_std_m=float(trans.std()),
        trans_max_m=float(trans.max()),
        rot_mean_deg=float(rot.mean()),
        rot_std_deg=float(rot.std()),
        rot_max_deg=float(rot.max()),
        trans_sq_mean_m2=float((trans**2).mean()),
        trans_sq_std_m2=float((trans**2).std()),
        rot_sq_mean_deg2=float((rot**2).mean()),
        rot_sq_std_deg2=float((rot**2).std()),
        translation_m=translation,
        rotation_deg=rotation,
    )
