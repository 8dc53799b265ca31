"""The Robot DB's map tables as the agent uses them: each step's map version, walls, pose and outbox entry
(recorded in one transaction), the current map and trajectory, the outbox folded into uploads, and the
map session id the uploads carry.

Walls are ``[id, x0, y0, x1, y1]`` (m), poses ``[stamp_s, x_m, y_m, theta_rad]``. A step is O(walls
changed); folding the outbox is O(versions x walls changed).

Compaction (the Robot DB grows with the map, not with the run): once the server confirms a version, the
map versions delivered before it are dropped (a delivered version's change is in the server's map and in
the ``walls`` table; the newest delivered one stays, with its scan stamp, for
:meth:`MapTables.stamp_of`), and the delivered poses are thinned past
:data:`shared.protocol.MAX_TRAJECTORY_POSES` by the rule the server applies
(:func:`shared.protocol.thin_positions`); a pose not yet delivered is never dropped. A snapshot's
trajectory is thinned the same way, so no upload carries the whole trajectory. With loop closure on, the
pose graph's keyframes that own none of the poses left go with them, and a later row for one is not
recorded (:func:`shared.protocol.keyframes_in_use`): a snapshot's keyframe rows, and a correction's,
stay about one per kept pose whatever the distance driven.
"""

from __future__ import annotations

import contextlib
import uuid
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from sqlalchemy import Table, bindparam, delete, func, insert, select, update
from sqlalchemy.dialects.sqlite import insert as sqlite_insert

from robot_agent.models import MapVersion, Meta, OutboxEntry, PoseRecord, Wall
from robot_agent.store_db import RobotDBFile, put_meta, put_metas, table_of
from robot_agent.store_resume import SavedState, write_resume
from shared.protocol import MAX_TRAJECTORY_POSES, correct_trajectory, keyframes_in_use, thin_positions

__all__ = ["MapTables", "PendingUpload", "StepRecord"]


@dataclass(frozen=True, slots=True)
class StepRecord:
    """What one step changed: new or changed walls ``[id, x0, y0, x1, y1]``, removed ids, the pose row
    ``[stamp_s, x_m, y_m, theta_rad]``, the latest centroids, and the source position (scans consumed).
    With loop closure on (:mod:`shared.protocol.posegraph`): the keyframes that are new or were moved
    ``[keyframe_id, stamp_s, x_m, y_m, theta_rad]``, the new loop closures ``[id_a, id_b]``, and the
    pose's covariance (3x3, None: the pipeline has none)."""

    version: int
    stamp_s: float
    source_index: int
    segments: list[list[float]]
    removed: list[int]
    pose: list[float]
    centroids: list[list[float]]
    keyframes: list[list[float]] = field(default_factory=list)
    loop_closures: list[list[int]] = field(default_factory=list)
    pose_covariance: list[list[float]] | None = None
    graph: bool = False  # the pipeline has a pose graph (its rows go on the wire, even when empty)


@dataclass(frozen=True, slots=True)
class PendingUpload:
    """Consecutive outbox versions folded into one delta."""

    first_version: int
    version: int
    stamp_s: float
    segments: list[list[float]]
    removed: list[int]
    centroids: list[list[float]]
    pose: list[float]
    trajectory: list[list[float]]
    keyframes: list[list[float]] | None = None
    loop_closures: list[list[int]] | None = None
    pose_covariance: list[list[float]] | None = None


# the step's statements, built once (Core on the tables: the ORM's bulk path cost as much as the SQL)
_INSERT_VERSION = insert(table_of(MapVersion))
_INSERT_POSE = insert(table_of(PoseRecord))
_INSERT_OUTBOX = insert(table_of(OutboxEntry))
_wall_upsert = sqlite_insert(table_of(Wall))
_UPSERT_WALL = _wall_upsert.on_conflict_do_update(
    index_elements=["segment_id"],
    set_={c: getattr(_wall_upsert.excluded, c) for c in ("x0_m", "y0_m", "x1_m", "y1_m")},
)


class MapTables(RobotDBFile):
    """The map and outbox methods of :class:`robot_agent.store.RobotDB`."""

    #: poses kept (delivered ones thinned past it; tests lower it)
    max_poses: int = MAX_TRAJECTORY_POSES

    def record_step(
        self, rec: StepRecord, scan: bytes | None = None, saved: SavedState | None = None
    ) -> None:
        """Store one step's map version, walls, pose and outbox entry in one transaction; with them the
        step's journaled ``scan`` and, when one is due, the mapping state ``saved`` after this step
        (:func:`robot_agent.store_resume.write_resume`). Core statements, not the ORM's unit of work: a
        step is the robot's most frequent write (10 Hz), and the ORM's flush cost it about twice as much."""
        with self.tx() as s:
            write_resume(s, rec.version, scan, saved)
            # the current keyframes and closures kept for snapshots: written when a step changes them
            # (and once to start), so a step that changes none costs no statement more; rows of keyframes
            # dropped with the poses they owned are left out of the record (_keep_graph)
            if rec.graph and (rec.keyframes or rec.loop_closures or not getattr(self, "_graph_kept", False)):
                rec = _keep_graph(s, rec)
                self._graph_kept = True
            s.execute(
                _INSERT_VERSION,
                {
                    "version": rec.version,
                    "stamp_s": rec.stamp_s,
                    "source_index": rec.source_index,
                    "change": {
                        "segments": rec.segments,
                        "removed": rec.removed,
                        "centroids": rec.centroids,
                        **_graph_change(rec),
                    },
                },
            )
            if rec.removed:
                s.execute(delete(Wall).where(Wall.segment_id.in_(rec.removed)))
            if rec.segments:
                s.execute(
                    _UPSERT_WALL,
                    [
                        {"segment_id": int(r[0]), "x0_m": r[1], "y0_m": r[2], "x1_m": r[3], "y1_m": r[4]}
                        for r in rec.segments
                    ],
                )
            s.execute(
                _INSERT_POSE,
                {
                    "version": rec.version,
                    "stamp_s": rec.pose[0],
                    "x_m": rec.pose[1],
                    "y_m": rec.pose[2],
                    "theta_rad": rec.pose[3],
                },
            )
            s.execute(_INSERT_OUTBOX, {"version": rec.version})
            put_metas(s, {"map_version": rec.version, "source_index": rec.source_index})

    def walls(self) -> list[list[float]]:
        """The current map's walls ``[id, x0, y0, x1, y1]`` by id."""
        with self._factory() as s:
            rows = s.execute(
                select(Wall.segment_id, Wall.x0_m, Wall.y0_m, Wall.x1_m, Wall.y1_m).order_by(Wall.segment_id)
            )
            return [[float(i), a, b, c, d] for i, a, b, c, d in rows]

    def trajectory(self, after_version: int = 0) -> list[list[float]]:
        with self._factory() as s:
            rows = s.execute(
                select(PoseRecord.stamp_s, PoseRecord.x_m, PoseRecord.y_m, PoseRecord.theta_rad)
                .where(PoseRecord.version > after_version)
                .order_by(PoseRecord.version)
            )
            return [list(r) for r in rows]

    def snapshot(self) -> dict[str, Any] | None:
        """The whole map at the latest recorded version (a snapshot upload), consistent with that version.

        pysqlite runs SELECTs outside a transaction, so each statement here would see the newest commit:
        a step recorded in between put its pose into a snapshot labelled one version earlier, and the next
        delta sent that pose again (the server held one pose more than map versions). So the read holds the
        writers' lock (this process is the Robot DB's only writer) and the trajectory stops at the
        snapshot's version."""
        with self._lock, self._factory() as s, s.begin():
            latest = s.scalar(select(func.max(MapVersion.version)))
            if latest is None:
                return None
            mv = s.get(MapVersion, latest)
            pose = s.get(PoseRecord, latest)
            assert mv is not None and pose is not None
            walls = s.execute(
                select(Wall.segment_id, Wall.x0_m, Wall.y0_m, Wall.x1_m, Wall.y1_m).order_by(Wall.segment_id)
            )
            traj = s.execute(
                select(PoseRecord.stamp_s, PoseRecord.x_m, PoseRecord.y_m, PoseRecord.theta_rad)
                .where(PoseRecord.version <= latest)
                .order_by(PoseRecord.version)
            )
            return {
                "version": int(latest),
                "stamp_s": mv.stamp_s,
                "segments": [[float(i), a, b, c, d] for i, a, b, c, d in walls],
                "centroids": mv.change.get("centroids", []),
                "pose": [pose.x_m, pose.y_m, pose.theta_rad],
                "trajectory": _thinned([list(r) for r in traj], self.max_poses),
                **_graph_snapshot(s, mv.change),
            }

    def outbox_size(self) -> int:
        with self._factory() as s:
            return int(s.scalar(select(func.count()).select_from(OutboxEntry)) or 0)

    def pending_upload(self, limit: int = 50) -> PendingUpload | None:
        """The oldest ``limit`` outbox versions folded into one delta (later changes win), or ``None``.

        The poses read are the recorded ones as corrected since (:func:`_correct_poses`), so by every
        version recorded so far, while the keyframe rows folded are those of the batch's versions only.
        When later versions are left out (the outbox holds more than ``limit``), a keyframe they moved has
        already moved the batch's poses it owns; the server would move them again when the later version
        arrives. So the delta then carries the kept (current) row of every keyframe that owns one of its
        poses: the server moves what it holds with it once, and the later version's row finds it there.
        Read under the writers' lock, so the poses, the kept rows and what is left out agree.
        O(limit + keyframes)."""
        with self._lock, self._factory() as s, s.begin():
            rows = list(
                s.execute(
                    select(MapVersion, PoseRecord)
                    .join(OutboxEntry, OutboxEntry.version == MapVersion.version)
                    .join(PoseRecord, PoseRecord.version == MapVersion.version)
                    .order_by(MapVersion.version)
                    .limit(limit)
                )
            )
            owners: list[list[float]] = []
            if len(rows) == limit and s.scalar(
                select(func.count()).select_from(OutboxEntry).where(OutboxEntry.version > rows[-1][0].version)
            ):
                owners = _owning_keyframes(s, rows[0][1].stamp_s, rows[-1][1].stamp_s)
        if not rows:
            return None
        segments: dict[int, list[float]] = {}
        removed: set[int] = set()
        keyframes: dict[int, list[float]] | None = None
        closures: list[list[int]] | None = None
        for mv, _pose in rows:
            if "keyframes" in mv.change:  # a step of the pose graph: later poses of a keyframe win
                keyframes = keyframes if keyframes is not None else {}
                keyframes.update({int(r[0]): r for r in mv.change["keyframes"]})
                closures = [*(closures or []), *mv.change.get("loop_closures", [])]
            for sid in mv.change.get("removed", []):
                segments.pop(int(sid), None)
                removed.add(int(sid))
            for row in mv.change.get("segments", []):
                segments[int(row[0])] = row
                removed.discard(int(row[0]))
        if owners:
            keyframes = keyframes if keyframes is not None else {}
            keyframes.update({int(r[0]): r for r in owners})
        last_mv, last_pose = rows[-1]
        traj = [[p.stamp_s, p.x_m, p.y_m, p.theta_rad] for _, p in rows]
        return PendingUpload(
            first_version=rows[0][0].version,
            version=last_mv.version,
            stamp_s=last_mv.stamp_s,
            segments=[segments[k] for k in sorted(segments)],
            removed=sorted(removed),
            centroids=last_mv.change.get("centroids", []),
            pose=[last_pose.x_m, last_pose.y_m, last_pose.theta_rad],
            trajectory=traj,
            keyframes=None if keyframes is None else [keyframes[k] for k in sorted(keyframes)],
            loop_closures=closures,
            pose_covariance=last_mv.change.get("pose_covariance"),
        )

    def mark_uploaded(self, up_to_version: int) -> None:
        """The server holds every version up to ``up_to_version``: drop them from the outbox, and compact
        what was delivered (module docstring). O(versions delivered), plus O(max poses) when the poses
        are thinned (once per ~max poses / 4 steps)."""
        with self.tx() as s:
            s.execute(delete(OutboxEntry).where(OutboxEntry.version <= up_to_version))
            s.execute(delete(MapVersion).where(MapVersion.version < up_to_version))
            put_meta(s, "uploaded_version", up_to_version)
            self._thin_poses(s, up_to_version)

    def _thin_poses(self, s: Any, delivered: int) -> None:
        over = s.execute(
            select(PoseRecord.version).order_by(PoseRecord.version.desc()).limit(1).offset(self.max_poses)
        ).first()
        if over is None:
            return
        versions = [int(v) for v in s.scalars(select(PoseRecord.version).order_by(PoseRecord.version))]
        drop = [versions[i] for i in thin_positions(len(versions), self.max_poses)]
        drop = [v for v in drop if v <= delivered]  # what is not delivered yet is sent first
        for start in range(0, len(drop), 500):
            s.execute(delete(PoseRecord).where(PoseRecord.version.in_(drop[start : start + 500])))
        if drop:
            _prune_graph(s)

    def size_bytes(self) -> int:
        """The Robot DB's size on disk (the file and its write-ahead log), in bytes."""
        total = 0
        for suffix in ("", "-wal", "-shm"):
            with contextlib.suppress(FileNotFoundError):
                total += self.path.with_name(self.path.name + suffix).stat().st_size
        return total

    # ------------------------------------------------------------ map session
    def stamp_of(self, version: int) -> float | None:
        """The scan time stamp of recorded map ``version`` (None: not recorded, or compacted away)."""
        with self.tx() as s:
            got = s.execute(select(MapVersion.stamp_s).where(MapVersion.version == version)).scalar()
        return None if got is None else float(got)

    def map_session(self) -> str:
        """The id of the map session this Robot DB's map belongs to (docs/reliability/identity.md): made
        by the migration that created the Robot DB, or by :meth:`new_map_session`."""
        value = self.get("map_session")
        if value is None:  # a Robot DB whose meta lost it: a new session, never a guess
            return self.new_map_session("the Robot DB had no map session id")
        return str(value)

    def delivered_map(self) -> tuple[str, int | None]:
        """This Robot DB's map session and the newest version the server confirmed in it (None: none yet),
        read together (a new session resets the version)."""
        with self._factory() as s, s.begin():  # one read transaction: both from the same commit
            rows = {
                m.key: m.value.get("v")
                for m in s.scalars(select(Meta).where(Meta.key.in_(("map_session", "uploaded_version"))))
            }
        if rows.get("map_session") is None:
            return self.map_session(), None  # a Robot DB whose meta lost it: a new session
        version = rows.get("uploaded_version")
        return str(rows["map_session"]), None if version is None else int(version)

    def map_session_reason(self) -> str | None:
        """Why the current map session began (sent with its snapshots)."""
        value = self.get("map_session_reason")
        return None if value is None else str(value)

    def new_map_session(self, reason: str) -> str:
        """Start a new map session (a new UUID): the map goes on, the server gets it as a new map from the
        next snapshot. Nothing counts as uploaded in the new session."""
        session = str(uuid.uuid4())
        with self.tx() as s:
            put_meta(s, "map_session", session)
            put_meta(s, "map_session_reason", reason[:300])
            put_meta(s, "uploaded_version", None)
        return session

    def note_attempt(self, version: int) -> None:
        with self.tx() as s:
            row = s.get(OutboxEntry, version)
            if row is not None:
                row.attempts += 1


def _thinned(rows: list[list[float]], max_poses: int = MAX_TRAJECTORY_POSES) -> list[list[float]]:
    """``rows`` thinned to at most ``max_poses`` by :func:`shared.protocol.thin_positions`. O(rows)."""
    drop = set(thin_positions(len(rows), max_poses))
    return [r for i, r in enumerate(rows) if i not in drop] if drop else rows


# ------------------------------------------------------------ the pose graph's rows
#: meta keys holding the pose graph's current keyframes and loop closures (for snapshots)
_KEYFRAMES_META, _CLOSURES_META = "graph_keyframes", "graph_loop_closures"


def _graph_change(rec: StepRecord) -> dict[str, Any]:
    """A step's pose-graph part of its recorded change (nothing for a pipeline without a graph)."""
    out: dict[str, Any] = {}
    if rec.graph:
        out["keyframes"] = rec.keyframes
        out["loop_closures"] = rec.loop_closures
    if rec.pose_covariance is not None:
        out["pose_covariance"] = rec.pose_covariance
    return out


def _keep_graph(s: Any, rec: StepRecord) -> StepRecord:
    """Fold a step's keyframes and loop closures into the current ones kept in meta (what a snapshot
    sends); ``rec`` without the rows of keyframes :func:`_prune_graph` dropped (not kept, older than the
    newest kept: they own no pose kept here or on the server, :mod:`shared.protocol.posegraph`), and the
    closures reaching them. O(kept keyframes)."""
    kept = s.get(Meta, _KEYFRAMES_META)
    rows = {int(r[0]): r for r in ((kept.value or {}).get("v") or [])} if kept is not None else {}
    newest = max(rows, default=-1)

    def dropped(k: int) -> bool:
        return k not in rows and k < newest

    rec = replace(
        rec,
        keyframes=[r for r in rec.keyframes if not dropped(int(r[0]))],
        loop_closures=[c for c in rec.loop_closures if not (dropped(int(c[0])) or dropped(int(c[1])))],
    )
    _correct_poses(s, rows, rec.keyframes)
    rows.update({int(r[0]): r for r in rec.keyframes})
    put_meta(s, _KEYFRAMES_META, [rows[k] for k in sorted(rows)])
    if rec.loop_closures or s.get(Meta, _CLOSURES_META) is None:
        got = s.get(Meta, _CLOSURES_META)
        closures = list((got.value or {}).get("v") or []) if got is not None else []
        seen = {(int(a), int(b)) for a, b in closures}
        put_meta(s, _CLOSURES_META, [*closures, *(c for c in rec.loop_closures if (c[0], c[1]) not in seen)])
    return rec


def _prune_graph(s: Any) -> None:
    """Drop the kept keyframes that own none of the poses kept, and the loop closures reaching them
    (:func:`shared.protocol.keyframes_in_use`, the server's rule): the rows a snapshot carries stay
    about one per kept pose whatever the distance driven. O(poses + keyframes), after a thinning."""
    kept = s.get(Meta, _KEYFRAMES_META)
    rows = list((kept.value or {}).get("v") or []) if kept is not None else []
    if not rows:
        return
    stamps = s.scalars(select(PoseRecord.stamp_s)).all()
    used = keyframes_in_use(rows, stamps)
    if len(used) == len(rows):
        return
    put_meta(s, _KEYFRAMES_META, [r for r in rows if int(r[0]) in used])
    got = s.get(Meta, _CLOSURES_META)
    if got is not None:
        closures = (got.value or {}).get("v") or []
        put_meta(s, _CLOSURES_META, [c for c in closures if int(c[0]) in used and int(c[1]) in used])


def _owning_keyframes(s: Any, first_s: float, last_s: float) -> list[list[float]]:
    """The kept keyframe rows that own a pose stamped in ``[first_s, last_s]``: the last one at or before
    ``first_s`` and those stamped within (the owner rule of
    :func:`shared.protocol.posegraph.correct_trajectory`). O(keyframes)."""
    kept = s.get(Meta, _KEYFRAMES_META)
    rows = sorted(((kept.value or {}).get("v") or []) if kept is not None else [], key=lambda r: (r[1], r[0]))
    before = [r for r in rows if float(r[1]) <= first_s]
    return [*before[-1:], *(r for r in rows if first_s < float(r[1]) <= last_s)]


def _correct_poses(s: Any, kept: dict[int, list[float]], rows: list[list[float]]) -> None:
    """Move the recorded poses after each keyframe that ``rows`` move with it (the rule the server and
    the dashboard apply to what they hold: :func:`shared.protocol.posegraph.correct_trajectory`), so that
    unsent deltas and later snapshots carry the corrected trajectory. O(poses after the earliest moved
    keyframe)."""
    moved = {int(r[0]): r[1:] for r in rows if int(r[0]) in kept and list(r[1:]) != list(kept[int(r[0])][1:])}
    if not moved:
        return
    before = {k: r[1:] for k, r in kept.items()}
    since = min(float(before[k][0]) for k in moved)
    poses: Table = PoseRecord.__table__  # type: ignore[assignment]
    got = s.execute(
        select(poses.c.version, poses.c.stamp_s, poses.c.x_m, poses.c.y_m, poses.c.theta_rad).where(
            poses.c.stamp_s >= since
        )
    ).all()
    if not got:
        return
    table = np.array(got, dtype=np.float64).reshape(-1, 5)
    fixed = correct_trajectory(table[:, 1:], before, moved)
    s.execute(
        update(poses)
        .where(poses.c.version == bindparam("v"))
        .values(x_m=bindparam("x"), y_m=bindparam("y"), theta_rad=bindparam("th")),
        [
            {"v": int(v), "x": x, "y": y, "th": th}
            for v, (_t, x, y, th) in zip(table[:, 0].tolist(), fixed.tolist(), strict=True)
        ],
    )


def _graph_snapshot(s: Any, change: dict[str, Any]) -> dict[str, Any]:
    """A snapshot's pose-graph fields: the kept keyframes and closures (absent without a graph) and the
    latest step's covariance."""
    out: dict[str, Any] = {}
    kept = s.get(Meta, _KEYFRAMES_META)
    if kept is not None:
        out["keyframes"] = (kept.value or {}).get("v") or []
        got = s.get(Meta, _CLOSURES_META)
        out["loop_closures"] = ((got.value or {}).get("v") or []) if got is not None else []
    if change.get("pose_covariance") is not None:
        out["pose_covariance"] = change["pose_covariance"]
    return out
