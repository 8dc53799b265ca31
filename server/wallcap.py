"""The wall cap of a robot's map (server setting ``max_walls_per_map``): whether an upload would make the
map hold more walls than allowed. :mod:`server.mapstore` calls it in the upload's transaction with the
walls stored before and after a delta (:mod:`server.mapcounts`); :mod:`server.parsepool` calls it on the
body alone."""

from __future__ import annotations

from server.errors import InvalidRequestError
from server.schemas import MapUpload

__all__ = ["check_wall_cap"]


def check_wall_cap(
    robot_id: int, up: MapUpload, cap: int, *, before: int | None = None, after: int | None = None
) -> None:
    """Refuse (422) an upload after which the robot's map would hold more than ``cap`` walls, unless it
    shrinks a map that is over the cap already. A snapshot is judged by its own walls; a delta by the
    walls stored ``before`` it and ``after`` it (without them, as on the body alone, it is not judged).
    O(walls in a snapshot), O(1) for a delta."""
    if up.base_version is None:
        before, after = 0, len({int(r[0]) for r in up.segments})
    elif before is None or after is None:
        return
    if after > cap and after > before:
        raise InvalidRequestError(
            f"robot {robot_id}'s map would hold {after} walls; the limit is {cap} walls per map "
            "(server setting max_walls_per_map)",
            max_walls_per_map=cap,
        )
