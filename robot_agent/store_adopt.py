"""The Robot DB takes over the map the server holds (``linemap agent --continue-map``,
:mod:`robot_agent.continuemap`): a new Robot DB becomes one that has recorded and delivered that map.

After :meth:`AdoptTables.adopt_map` the Robot DB holds the server's map session and version (recorded and
delivered: nothing of it is sent again), its walls with their ids, its trajectory as delivered poses (a
later snapshot carries it), a map version row at that version (scan stamp, centroids), and in meta
``continued_map`` what the mapping needs to go on from it: the session, version, scan stamp, pose and the
offset added to the pose graph's keyframe ids (the server's keyframes keep theirs). One transaction.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from sqlalchemy import func, insert, select

from robot_agent.errors import AgentError
from robot_agent.models import MapVersion, PoseRecord, Wall
from robot_agent.store_db import RobotDBFile, put_metas, table_of

__all__ = ["AdoptTables", "HeldMap"]

#: meta key of the continued map (:meth:`AdoptTables.continued_map`)
CONTINUED_META = "continued_map"


@dataclass(frozen=True, slots=True)
class HeldMap:
    """The map a server holds for this robot, as continued: ``version`` (>= 1) of ``session``, the scan
    stamp it was made at (s), walls ``[id, x0, y0, x1, y1]`` (m), the latest centroids ``[x, y]``, the
    pose ``(x_m, y_m, theta_rad)``, the trajectory ``[stamp_s, x_m, y_m, theta_rad]`` (oldest first, the
    last one the pose's) and the largest keyframe id the server holds (-1: none)."""

    version: int
    session: str
    stamp_s: float
    segments: list[list[float]]
    centroids: list[list[float]]
    pose: tuple[float, float, float]
    trajectory: list[list[float]]
    max_keyframe_id: int = -1


class AdoptTables(RobotDBFile):
    """The adopting methods of :class:`robot_agent.store.RobotDB`."""

    def is_new(self) -> bool:
        """Whether this Robot DB has recorded no map version yet (a map may be adopted into it)."""
        with self._factory() as s:
            return s.scalar(select(func.count()).select_from(MapVersion)) == 0 and not self.get("map_version")

    def adopt_map(self, held: HeldMap) -> None:
        """Make this new Robot DB one that recorded and delivered ``held`` (module docstring).
        :class:`AgentError` if it has recorded a map version already. O(walls + trajectory)."""
        v = held.version
        trajectory = [list(r) for r in held.trajectory[-v:]]  # one pose per version at most
        if not trajectory or trajectory[-1][0] != held.stamp_s:
            trajectory.append([held.stamp_s, *held.pose])
            trajectory = trajectory[-v:]
        with self.tx() as s:
            if s.scalar(select(func.count()).select_from(MapVersion)):
                raise AgentError(
                    f"the Robot DB {self.path} has recorded a map of its own: only a new one continues "
                    "the server's map"
                )
            if held.segments:
                s.execute(
                    insert(table_of(Wall)),
                    [
                        {"segment_id": int(r[0]), "x0_m": r[1], "y0_m": r[2], "x1_m": r[3], "y1_m": r[4]}
                        for r in held.segments
                    ],
                )
            first = v - len(trajectory) + 1
            s.execute(
                insert(table_of(PoseRecord)),
                [
                    {"version": first + i, "stamp_s": r[0], "x_m": r[1], "y_m": r[2], "theta_rad": r[3]}
                    for i, r in enumerate(trajectory)
                ],
            )
            s.execute(
                insert(table_of(MapVersion)),
                {
                    "version": v,
                    "stamp_s": held.stamp_s,
                    "source_index": 0,
                    "change": {"segments": [], "removed": [], "centroids": held.centroids},
                },
            )
            put_metas(
                s,
                {
                    "map_session": held.session,
                    "map_session_reason": f"continued the server's map of session {held.session} at "
                    f"version {v}",
                    "map_version": v,
                    "uploaded_version": v,
                    "source_index": 0,
                    CONTINUED_META: {
                        "session": held.session,
                        "version": v,
                        "stamp_s": held.stamp_s,
                        "pose": list(held.pose),
                        "keyframe_offset": held.max_keyframe_id + 1,
                    },
                },
            )

    def continued_map(self) -> dict[str, Any] | None:
        """What :meth:`adopt_map` noted (``session``, ``version``, ``stamp_s``, ``pose``,
        ``keyframe_offset``), or None for a Robot DB that began its own map."""
        value = self.get(CONTINUED_META)
        return dict(value) if isinstance(value, dict) else None
