"""A snapshot upload as a diff against the robot's stored map: pure functions, NumPy arrays in and out.

A near-limit snapshot (20,000 walls, ~100,000 poses) written as a full replace deletes and re-inserts
~120,000 rows, holding SQLite's one write lock for 0.3-0.7 s while every other robot's upload waits.
A robot's consecutive snapshots mostly repeat what is stored: the same walls and the same trajectory,
extended. :func:`diff_snapshot` (run in the parser worker process, :mod:`server.parsepool`) finds what
differs, and the write transaction (:func:`server.mapstore.apply_upload`) applies only that:

- walls: stored ids the snapshot lacks are deleted; the snapshot's walls that are new or whose
  coordinates differ (bit for bit, so ``-0.0`` and ``0.0`` count as different) are upserted;
- trajectory: when the snapshot's poses start with the stored ones (bit for bit), the rest is appended;
  otherwise the stored trajectory is replaced whole;
- centroids, pose and stamps live in one row and are written whole as before.

:func:`apply_diff` is the same change applied to arrays: ``apply_diff(stored, diff_snapshot(stored, ...))``
is exactly the snapshot's map (the property tests check it). The diff is valid only against the version
it was computed from (``SnapshotDiff.base_version``); the writer compares it with the stored version inside
its transaction and falls back to the full replace when the map moved.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["SnapshotDiff", "StoredMap", "apply_diff", "diff_snapshot", "last_rows"]

FloatRows = NDArray[np.float64]
IdArray = NDArray[np.int64]


@dataclass(frozen=True, slots=True)
class StoredMap:
    """A robot's stored map at ``version``: wall ids ascending (``[n]``), their coordinates in metres
    (``[n, 4]``: x0, y0, x1, y1), and the trajectory poses in stored order (``[k, 4]``: stamp_s, x_m,
    y_m, theta_rad)."""

    version: int
    wall_ids: IdArray
    walls: FloatRows
    trajectory: FloatRows


@dataclass(frozen=True, slots=True)
class SnapshotDiff:
    """What turns the stored map of ``base_version`` into a snapshot's map: wall ids to delete, wall rows
    to upsert (``[u, 5]``: id, x0, y0, x1, y1, ascending ids), and the poses to insert after deleting the
    stored trajectory (``replace_trajectory``) or after keeping it (append)."""

    base_version: int
    removed: IdArray
    upsert: FloatRows
    replace_trajectory: bool
    trajectory: FloatRows

    @property
    def rows(self) -> int:
        """Rows the write touches (deleted walls, upserted walls, inserted poses)."""
        return len(self.removed) + len(self.upsert) + len(self.trajectory)


def _bits(a: FloatRows) -> NDArray[np.int64]:
    """The float64 values as their bit patterns, for exact comparison."""
    return np.ascontiguousarray(a, dtype=np.float64).view(np.int64)


def last_rows(segments: FloatRows) -> tuple[IdArray, FloatRows]:
    """A snapshot's walls as (ids ascending, coordinates ``[n, 4]``), a wall id given twice keeping its last
    row (what the full replace stores: ``server.mapstore.prepare_rows``). Ids are truncated to integers
    like ``int()`` does."""
    segments = np.asarray(segments, dtype=np.float64).reshape(-1, 5)
    ids = segments[:, 0].astype(np.int64)
    rev_ids = ids[::-1]
    uniq, first_in_rev = np.unique(rev_ids, return_index=True)  # sorted; first in reverse = last given
    rows = segments[::-1][first_in_rev]
    return uniq.astype(np.int64), np.ascontiguousarray(rows[:, 1:5])


def diff_snapshot(stored: StoredMap, segments: FloatRows, trajectory: FloatRows) -> SnapshotDiff:
    """The diff from ``stored`` to the snapshot of walls ``segments`` (``[m, 5]``, any order, ids may
    repeat) and poses ``trajectory`` (``[t, 4]``). O((n + m) log(n + m) + k + t)."""
    new_ids, new_walls = last_rows(segments)
    trajectory = np.asarray(trajectory, dtype=np.float64).reshape(-1, 4)
    old_ids = np.asarray(stored.wall_ids, dtype=np.int64)
    old_walls = np.asarray(stored.walls, dtype=np.float64).reshape(-1, 4)
    removed = np.setdiff1d(old_ids, new_ids, assume_unique=True).astype(np.int64)
    changed = np.ones(len(new_ids), dtype=bool)
    if len(old_ids):
        pos = np.minimum(np.searchsorted(old_ids, new_ids), len(old_ids) - 1)
        present = old_ids[pos] == new_ids
        same = present & np.all(_bits(old_walls[pos]) == _bits(new_walls), axis=1)
        changed = ~same
    upsert = np.column_stack([new_ids[changed].astype(np.float64), new_walls[changed]]).reshape(-1, 5)
    old_traj = np.asarray(stored.trajectory, dtype=np.float64).reshape(-1, 4)
    k = len(old_traj)
    extends = len(trajectory) >= k and bool(np.array_equal(_bits(trajectory[:k]), _bits(old_traj)))
    return SnapshotDiff(
        base_version=stored.version,
        removed=removed,
        upsert=np.ascontiguousarray(upsert),
        replace_trajectory=not extends,
        trajectory=np.ascontiguousarray(trajectory[k:] if extends else trajectory),
    )


def apply_diff(stored: StoredMap, diff: SnapshotDiff) -> tuple[IdArray, FloatRows, FloatRows]:
    """``stored`` changed by ``diff``, as (wall ids ascending, wall coordinates, trajectory): what the
    database holds after the diff's write. Raises ``ValueError`` when ``diff`` is for another version."""
    if diff.base_version != stored.version:
        raise ValueError(f"diff from version {diff.base_version} applied to version {stored.version}")
    walls = {int(i): row for i, row in zip(stored.wall_ids, np.asarray(stored.walls), strict=True)}
    for i in diff.removed:
        del walls[int(i)]
    for row in diff.upsert:
        walls[int(row[0])] = row[1:5]
    ids = np.array(sorted(walls), dtype=np.int64)
    coords = np.array([walls[int(i)] for i in ids], dtype=np.float64).reshape(-1, 4)
    kept = np.empty((0, 4)) if diff.replace_trajectory else np.asarray(stored.trajectory).reshape(-1, 4)
    return ids, coords, np.concatenate([kept, diff.trajectory]).reshape(-1, 4)
