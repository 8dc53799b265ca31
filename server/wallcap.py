"""The wall cap of a robot's map (server setting ``max_walls_per_map``): whether an upload would make the
map hold more walls than allowed. Split from :mod:`server.mapstore`, which calls it in the upload's
transaction; :mod:`server.parsepool` calls it on the body alone."""

from __future__ import annotations

from sqlalchemy import Connection, Table, func, select

from server.errors import InvalidRequestError
from server.models import MapSegment
from server.schemas import MapUpload

__all__ = ["check_wall_cap"]

_SEG: Table = MapSegment.__table__  # type: ignore[assignment]
_CHUNK_ROWS = 500  # ids per IN list: well under SQLite's and PostgreSQL's parameter limits


def _count(conn: Connection, robot_id: int, ids: list[int] | None = None) -> int:
    """Walls of ``robot_id`` stored now (among ``ids`` if given). O(walls) on the primary-key index."""
    if ids is None:
        q = select(func.count()).select_from(_SEG).where(_SEG.c.robot_id == robot_id)
        return int(conn.execute(q).scalar_one())
    n = 0
    for start in range(0, len(ids), _CHUNK_ROWS):
        chunk = ids[start : start + _CHUNK_ROWS]
        q = select(func.count()).where(_SEG.c.robot_id == robot_id, _SEG.c.segment_id.in_(chunk))
        n += int(conn.execute(q).scalar_one())
    return n


def _walls_after(
    conn: Connection, robot_id: int, up: MapUpload, cap: int, stored: int | None = None
) -> tuple[int, int]:
    """(walls stored now, walls after ``up``) for a delta; exact when it matters, i.e. when the map could
    pass ``cap``. One count query for the common case (none when ``stored`` gives it), O(upload) more
    near the cap."""
    before = _count(conn, robot_id) if stored is None else stored
    ids = {int(r[0]) for r in up.segments}
    if before + len(ids) <= cap:
        return before, before + len(ids)  # an upper bound, under the cap: enough
    removed = set(up.removed)
    gone = _count(conn, robot_id, sorted(removed))  # stored walls the delta removes
    kept_ids = sorted(ids - removed)
    stay = _count(conn, robot_id, kept_ids)  # stored walls it only changes
    return before, before - gone + len(ids) - stay


def check_wall_cap(
    conn: Connection | None,
    robot_id: int,
    up: MapUpload,
    cap: int,
    stored: int | None = None,
    *,
    after: int | None = None,
) -> None:
    """Refuse (422) an upload after which the robot's map would hold more than ``cap`` walls, unless it
    shrinks a map that is over the cap already. ``conn`` None: only what the body alone shows (a
    snapshot's walls), no database. ``stored``: the robot's walls stored now, if read already; ``after``:
    with ``stored``, the walls after the upload (:mod:`server.mapcounts`), so nothing is counted."""
    if up.base_version is None:
        before, after = 0, len({int(r[0]) for r in up.segments})
    elif conn is None:
        return
    elif stored is not None and after is not None:
        before = stored
    else:
        before, after = _walls_after(conn, robot_id, up, cap, stored)
    if after > cap and after > before:
        raise InvalidRequestError(
            f"robot {robot_id}'s map would hold {after} walls; the limit is {cap} walls per map "
            "(server setting max_walls_per_map)",
            max_walls_per_map=cap,
        )
