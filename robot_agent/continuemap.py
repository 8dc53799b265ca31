"""``linemap agent --continue-map``: a new Robot DB continues the map the server holds for this robot
instead of starting a new one (docs/reliability/identity.md, "Continuing the server's map").

At start, before mapping: a Robot DB that has recorded nothing reads ``GET /robots/{id}/maps/latest`` and
takes it over (:meth:`robot_agent.store.RobotDB.adopt_map`): the same map session, the next version after
the server's, the walls with their ids. The mapping then starts its pipeline from those walls at the
server's last pose (:meth:`shared.pipeline.Pipeline.continue_map`; :mod:`robot_agent.mapping` skips the
scans of a replayed source up to the server's last scan stamp and takes the odometry there). A Robot DB
that holds a map of its own goes on with it (the flag is kept in a service's command line across restarts:
it then does nothing). No server, a server that cannot be read, or a map that cannot be continued is an
:class:`~robot_agent.errors.AgentError` naming why: the operator asked for that map, and a new one would
not be what was asked for.
"""

from __future__ import annotations

import logging
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, FiniteFloat

from robot_agent.errors import AgentError, LinkError
from robot_agent.link import ServerLink
from robot_agent.store import HeldMap, RobotDB
from shared.protocol import MAP_SESSION_PATTERN

__all__ = ["continue_server_map"]

log = logging.getLogger(__name__)


_Wall = Annotated[list[FiniteFloat], Field(min_length=5, max_length=5)]  # [id, x0, y0, x1, y1]
_Point = Annotated[list[FiniteFloat], Field(min_length=2, max_length=2)]
_Pose = Annotated[list[FiniteFloat], Field(min_length=3, max_length=3)]
_Stamped = Annotated[list[FiniteFloat], Field(min_length=4, max_length=4)]  # [stamp_s, x, y, theta]


class _HeldAnswer(BaseModel):
    """The part of ``GET /robots/{id}/maps/latest`` a continued map takes (server.schemas.MapOut)."""

    model_config = ConfigDict(extra="ignore")

    version: int = Field(ge=0)
    map_session: str | None = Field(None, pattern=MAP_SESSION_PATTERN)
    stamp_s: FiniteFloat
    segments: list[_Wall]
    centroids: list[_Point]
    pose: _Pose
    trajectory: list[_Stamped]
    keyframes: list[_Wall] | None = None  # [keyframe_id, stamp_s, x, y, theta]


def continue_server_map(link: ServerLink | None, db: RobotDB) -> str:
    """Take over the server's map of this robot into ``db`` if ``db`` is new (module docstring); returns
    what was done, for the log. O(walls + trajectory)."""
    if not db.is_new():
        return (
            f"--continue-map: the Robot DB holds a map of its own (version {db.get('map_version')}); it goes "
            "on with it (only a new Robot DB continues the server's map)"
        )
    if link is None:
        raise AgentError(
            "--continue-map needs the server (--server, --robot-id, --token): it continues the "
            "map the server holds for this robot"
        )
    robot = link.robot_id
    try:
        got = link.read(f"/robots/{robot}/maps/latest", _HeldAnswer)
    except LinkError as exc:
        raise AgentError(
            f"--continue-map: the server's map of robot {robot} could not be read ({exc}); start again once "
            "the server answers, or without --continue-map for a new map"
        ) from None
    if got.version == 0:
        return f"--continue-map: the server holds no map of robot {robot}: a new map starts"
    if got.map_session is None:
        raise AgentError(
            f"--continue-map: the server's map of robot {robot} (version {got.version}) has no map session "
            "(an agent from before sessions uploaded it): it cannot be continued; start without "
            "--continue-map for a new map"
        )
    ids = [r[0] for r in got.segments]
    if any(i != int(i) or i < 0 for i in ids) or len(set(ids)) != len(ids):
        raise AgentError(
            f"--continue-map: the server's map of robot {robot} has wall ids that are not distinct "
            "non-negative integers: it cannot be continued"
        )
    held = HeldMap(
        version=got.version,
        session=got.map_session,
        stamp_s=got.stamp_s,
        segments=[list(r) for r in got.segments],
        centroids=[list(r) for r in got.centroids],
        pose=(got.pose[0], got.pose[1], got.pose[2]),
        trajectory=[list(r) for r in got.trajectory],
        max_keyframe_id=max((int(k[0]) for k in got.keyframes or ()), default=-1),
    )
    db.adopt_map(held)
    x, y, th = held.pose
    return (
        f"--continue-map: continued the server's map of robot {robot}: session {held.session} at version "
        f"{held.version}, {len(held.segments)} walls, from pose ({x:.3f} m, {y:.3f} m, {th:.4f} rad)"
    )
