"""``/robots/{id}/maps``: the robot uploads temporary maps; operators read the latest or stream them (SSE),
and list the robot's maps, one per mapping session (``GET /robots/{id}/maps``, :mod:`server.mapsessions`),
and the versions of the current one that can be replayed (``GET /robots/{id}/maps/history``,
:mod:`server.maphistory`).

Stream events (``text/event-stream``, :mod:`server.mapstream`): ``snapshot`` (the whole map,
:class:`server.schemas.MapOut`) first and whenever the subscriber must resynchronise, then one ``delta``
per upload (to any server process on the database), carrying ``version``, ``base_version``, changed
``segments``, ``removed`` ids, ``centroids``, ``pose`` and new ``trajectory`` rows. Each event's ``id`` is
the map version; a browser reconnecting with ``Last-Event-ID`` resumes after it (the deltas it missed,
from the delta log, or a snapshot). A comment line every 15 s keeps proxies from closing it. The stream
re-checks its credential every ``AUTH_RECHECK_S`` (:func:`server.deps.still_valid`: an answer read from
the database at most 0.5 s before) and ends when it no longer works (token revoked or rotated, on any
server process; session closed or expired).

``GET /export?format=geojson|svg|dxf|mcap|pgm|yaml`` returns the latest map as a file (the same writers as
``linemap map``; ``session=<id>``: that mapping session's map); ``pgm`` and ``yaml`` are the two halves
of a ROS map_server map at ``resolution`` metres per pixel, named
``robot-<id>-map-v<version>-<resolution>m.pgm/.yaml`` so that the YAML names its image.
A stored map with items outside the declared bounds (:mod:`server.mapbounds`; stored before the bounds
held) is refused with 409 naming them, or exported without them with ``out_of_bounds=skip`` (the response
header ``X-Map-Skipped`` then counts what was left out).
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from fastapi import APIRouter, Depends, Header, Query, Request, Response
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import StreamingResponse
from sqlalchemy import Connection

from server.deps import AgentChecked, AppState, Principal, RobotSelf, StateDep, robot_access
from server.errors import ConflictError, InvalidRequestError, RateLimitedError
from server.mapbounds import screen_stored
from server.maphistory import read_history
from server.maplog import LoggedUpload
from server.maplog import append as log_upload
from server.maplog import clear as clear_log
from server.mapread import list_sessions, map_version, read_held
from server.mapstore import AppliedUpload, apply_upload, prepare_rows, queue_upload_reads
from server.mapstream import map_events
from server.parsepool import UploadParser, parse_upload
from server.pgrows import PendingReads
from server.quota import UploadQuota
from server.schemas import DB_INT_MAX, DbIdPath, MapHistoryOut, MapOut, MapSessionOut, MapUpload, MapUploadOut
from shared.errors import InvalidInputError
from shared.export import EmptyMapError, ExportError
from shared.pipeline.snapshot import MapSnapshot
from shared.protocol import MAP_SESSION_PATTERN, MAX_TRAJECTORY_POSES, anchored
from shared.types import Pose2D

__all__ = ["router"]

router = APIRouter(prefix="/robots/{robot_id}/maps", tags=["maps"])
RobotAccess = Annotated[Principal, Depends(robot_access)]


_UPLOAD_BODY = {
    "requestBody": {
        "required": True,
        "content": {"application/json": {"schema": MapUpload.model_json_schema()}},
    }
}


#: Upload bodies up to this size are parsed and written on the event loop (a few ms); larger ones are
#: parsed in a worker process (server.parsepool) and written in the thread pool, so that a near-limit upload
#: (a 4 MB snapshot: ~0.5 s of parsing, ~1 s of writing) does not stall other clients.
INLINE_BODY_BYTES = 64 * 1024


def _charge(request: Request, robot_id: int, n_bytes: int) -> None:
    """Take one upload of ``n_bytes`` from the robot's quota (:mod:`server.quota`), or 429."""
    quota: UploadQuota = request.app.state.upload_quota
    wait_s = quota.take(robot_id, n_bytes)
    if wait_s is not None:
        raise RateLimitedError(
            f"robot {robot_id} is over its upload quota ({quota.limits()}): an upload of {n_bytes} bytes "
            f"passes in {wait_s:.1f} s",
            retry_after_s=wait_s,
        )


@router.post(
    "",
    response_model=MapUploadOut,
    response_model_exclude_none=True,
    openapi_extra=_UPLOAD_BODY,
    dependencies=[AgentChecked],
)
async def upload_map(
    robot_id: DbIdPath,
    request: Request,
    who: RobotSelf,
    state: StateDep,
    idempotency_key: Annotated[
        str | None,
        Header(
            max_length=100,
            description="Makes a retried upload a no-op; defaults to 'version-<version>' (with a map "
            "session: '<map_session>-version-<version>').",
        ),
    ] = None,
) -> MapUploadOut:
    """Upload a snapshot (``base_version`` null) or a delta (body: ``MapUpload``); 409 with
    ``current_version`` if the delta's base is not the server's version (send a snapshot then); 422 when
    the map would hold more than ``max_walls_per_map`` walls; 429 with ``Retry-After`` when the robot is
    over its upload quota (requests and bytes per second). Coordinates, ids, headings and stamps are
    checked against their declared bounds (:mod:`server.mapbounds`: 422 naming the field, value and bound)."""
    # The body is read before a refusal (cheap I/O, no parsing): a client cut off mid-body sees a broken
    # connection, not the 429 and its Retry-After.
    raw = await request.body()
    _charge(request, robot_id, len(raw))
    cap = state.settings.max_walls_per_map
    heavy, diff = len(raw) > INLINE_BODY_BYTES, None
    if heavy:  # a snapshot also gets its diff against the stored map (server.snapdiff)
        parser: UploadParser = request.app.state.upload_parser
        body, diff = await parser.parse(raw, robot_id, cap, state.settings.world_extent_m)
    else:
        body = parse_upload(raw, robot_id, cap, state.settings.world_extent_m)
    key = idempotency_key or (
        f"version-{body.version}"
        if body.map_session is None
        else f"{body.map_session}-version-{body.version}"
    )
    seen = state.last_seen(robot_id)
    rows = await run_in_threadpool(prepare_rows, robot_id, body, diff) if heavy else None  # before the writer

    queued: list[PendingReads | None] = [None]  # the lock and reads the write batch queued (PostgreSQL)

    def prefetch(conn: Connection) -> None:
        queued[0] = queue_upload_reads(conn, robot_id, body, key)

    def also(conn: Connection, applied: AppliedUpload) -> LoggedUpload:
        # the delta log and the notice to other processes commit with the map (server.maplog, server.hub),
        # written with the map's rows (on PostgreSQL in their round trip)
        if applied.new_session:  # the log holds the current session's uploads only: versions anew
            clear_log(conn, robot_id)
        assert applied.event is not None
        notice = state.hub.notice(f"maps:{robot_id}", body.version)  # sent with the log's entry
        return log_upload(conn, robot_id, applied.event, undo=applied.undo, notice=notice)

    def write(conn: Connection) -> AppliedUpload:
        pending, queued[0] = queued[0], None
        return apply_upload(conn, robot_id, body, key, seen, cap, rows, who.actor, pending=pending, also=also)

    applied = await state.writer.submit(write, heavy=heavy, key=robot_id, prefetch=prefetch)
    logged: LoggedUpload | None = applied.extra
    if applied.new_session:  # versions count anew: a version kept from the old session is another map
        state.recent_maps.forget(robot_id)
    if logged is not None:
        state.hub.publish(f"maps:{robot_id}", logged)  # the stream sends its JSON as is
        if diff is not None:  # the parser process may diff the robot's next snapshot against this one
            parser.wrote(robot_id, body.version)
    return applied.out


#: ``?version=N``: one version of the map (the current one, or one this process served lately)
VersionQuery = Annotated[
    int | None,
    Query(
        ge=0,
        le=DB_INT_MAX,
        description="This map version of the current session (the replayable ones: GET "
        "/robots/{id}/maps/history; 409 above the current, 410 older than the history holds, 404 a skipped "
        "number).",
    ),
]


#: ``?session=<uuid>``: the map of that mapping session (the current one or an ended one)
SessionQuery = Annotated[
    str | None,
    Query(
        pattern=anchored(MAP_SESSION_PATTERN),
        description="This mapping session's map (see GET /robots/{id}/maps); default: the current one.",
    ),
]


def _version(state: AppState, robot_id: int) -> tuple[str | None, int]:
    with state.db.read() as s:
        return map_version(s, robot_id)


def _sessions(state: AppState, robot_id: int) -> list[MapSessionOut]:
    with state.db.read() as s:
        return list_sessions(s, robot_id)


@router.get("", response_model=list[MapSessionOut])
async def list_maps(robot_id: DbIdPath, who: RobotAccess, state: StateDep) -> list[MapSessionOut]:
    """The robot's maps, one per mapping session, newest first: the current one and those a new session
    replaced (kept), each with its first and last version, when it started and was last uploaded, and its
    wall count."""
    return await run_in_threadpool(_sessions, state, robot_id)


def _history(state: AppState, robot_id: int) -> MapHistoryOut:
    with state.db.read() as s:
        return read_history(s, robot_id)


@router.get("/history", response_model=MapHistoryOut)
async def map_history(robot_id: DbIdPath, who: RobotAccess, state: StateDep) -> MapHistoryOut:
    """The versions of the robot's current mapping session that ``/latest?version=N`` and
    ``/export?version=N`` can replay (the dashboard's history slider), oldest first, with their scan time
    stamps, and in ``older`` why earlier ones cannot be. Each delta upload keeps what it replaced in the
    delta log, so a version is rebuilt by undoing the deltas above it: the range reaches back to the last
    snapshot upload (it replaced the whole map), to the start of the session, or as far as the log keeps
    (the last 256 uploads), whichever is nearest. Other sessions' maps: ``/latest?session=<id>``."""
    return await run_in_threadpool(_history, state, robot_id)


#: said in the OpenAPI document of the map reads: their size does not grow with the run's length
BOUNDED_DOC = (
    f"Bounded whatever the run's length: the server keeps at most {MAX_TRAJECTORY_POSES} trajectory poses "
    "of a map (past that, older poses are thinned: every recent pose, ever sparser older ones; the robot "
    "thins its uploads by the same rule), so the answer holds the walls, at most 200 centroids and at "
    "most that many poses."
)


_LATEST_DOC = (
    "The whole current map (version 0 and empty before the first upload); with `version`, that version of "
    "the current session (the versions held: `GET /robots/{id}/maps/history`; 409 with `current_version` "
    "for one above the current, 410 for one older than the history holds, 404 for a number the robot "
    "skipped); with `session`, that mapping session's map; with `trajectory=N`, only the last N poses. "
    + BOUNDED_DOC
)


@router.get("/latest", response_model=MapOut, description=_LATEST_DOC)
async def latest_map(
    robot_id: DbIdPath,
    who: RobotAccess,
    state: StateDep,
    trajectory: Annotated[
        int | None, Query(ge=0, le=DB_INT_MAX, description="Only the last N trajectory poses.")
    ] = None,
    version: VersionQuery = None,
    session: SessionQuery = None,
) -> MapOut:
    """The whole current map (version 0 and empty before the first upload); with ``version``, that
    version of the current session (the versions held: ``GET /robots/{id}/maps/history``; 409 with
    ``current_version`` for one above the current, 410 for one older than the history holds, 404 for a
    number the robot skipped); with ``session``, that mapping session's map (the OpenAPI description:
    ``_LATEST_DOC``)."""
    return await run_in_threadpool(read_held, state, robot_id, trajectory, version, session)


@router.get(
    "/stream", response_class=StreamingResponse, responses={200: {"content": {"text/event-stream": {}}}}
)
async def stream_map(
    robot_id: DbIdPath,
    request: Request,
    who: RobotAccess,
    state: StateDep,
    trajectory: Annotated[
        int | None, Query(ge=0, le=DB_INT_MAX, description="Trajectory poses in snapshots (last N).")
    ] = None,
    last_event_id: Annotated[
        int | None,
        Header(
            alias="Last-Event-ID",
            ge=0,
            le=DB_INT_MAX,
            description="Resume after this map version (a reconnecting browser sends it).",
        ),
    ] = None,
) -> StreamingResponse:
    """Server-sent events: a ``snapshot`` (or, with ``Last-Event-ID``, the deltas after that version),
    then a ``delta`` per upload (see the module docstring)."""
    await run_in_threadpool(_version, state, robot_id)  # 404 before the stream starts
    events = map_events(request, state, robot_id, trajectory, last_event_id, read_held)
    headers = {"Cache-Control": "no-cache", "X-Accel-Buffering": "no"}
    return StreamingResponse(events, media_type="text/event-stream", headers=headers)


_ExportFormat = Literal["geojson", "svg", "dxf", "mcap", "pgm", "yaml"]
_MEDIA_TYPES: dict[str, str] = {
    "geojson": "application/geo+json",
    "svg": "image/svg+xml",
    "dxf": "image/vnd.dxf",
    "mcap": "application/x-mcap",
    "pgm": "image/x-portable-graymap",
    "yaml": "application/yaml",
}


def _snapshot(m: MapOut) -> MapSnapshot:
    rows = np.asarray(m.segments, dtype=np.float64).reshape(-1, 5)
    return MapSnapshot(
        version=m.version,
        stamp_s=m.stamp_s,
        segments=rows[:, 1:],
        segment_ids=rows[:, 0].astype(np.intp),
        centroids=np.asarray(m.centroids, dtype=np.float64).reshape(-1, 2),
        pose=Pose2D(*m.pose),
        trajectory=np.asarray(m.trajectory, dtype=np.float64).reshape(-1, 4),
    )


def _export_name(m: MapOut, fmt: str, resolution_m: float) -> str:
    """The download's file name; the two files of a map_server map share one stem."""
    stem = f"robot-{m.robot_id}-map-v{m.version}"
    if fmt in ("pgm", "yaml"):
        stem += f"-{resolution_m:g}m"
    return f"{stem}.{fmt}"


def _write(m: MapOut, fmt: str, resolution_m: float) -> bytes:
    """The map in ``fmt`` as bytes, written by :mod:`shared.export`."""
    from shared.export import (
        encode_dxf,
        occupancy_files,
        rasterise_segments,
        render_map,
        write_geojson,
        write_map_mcap,
    )

    snap = _snapshot(m)
    if fmt == "dxf":
        return encode_dxf(snap)
    if fmt in ("pgm", "yaml"):
        try:
            grid = rasterise_segments(
                snap.segments, resolution_m=resolution_m, inside_xy=snap.trajectory[:, 1:3]
            )
        except EmptyMapError:
            raise ConflictError(
                f"robot {m.robot_id}'s map (version {m.version}) has no walls yet: nothing to rasterise"
            ) from None
        except InvalidInputError as exc:
            raise InvalidRequestError(str(exc)) from None
        pgm, text = occupancy_files(grid, _export_name(m, "pgm", resolution_m))
        return pgm if fmt == "pgm" else text.encode("utf-8")
    with tempfile.TemporaryDirectory(prefix="linemap-export-") as folder:
        target = Path(folder) / f"map.{fmt}"
        if fmt == "geojson":
            write_geojson(target, snap, extra_properties={"robot_id": m.robot_id})
        elif fmt == "mcap":
            write_map_mcap(target, snap)
        else:
            render_map(snap, target, title=f"linemap: robot {m.robot_id}, map version {m.version}")
        return target.read_bytes()


def _export(
    m: MapOut, fmt: str, resolution_m: float, extent_m: float, skip: bool
) -> tuple[bytes, dict[str, int]]:
    """The map in ``fmt`` as bytes and what was left out (in the thread pool: rasterising and drawing take
    up to a second for large maps). Stored items outside the declared bounds: 409 naming them, or left out
    with ``skip``. A writer that still cannot write the stored map answers 409 with its reason."""
    screen = screen_stored(m, extent_m)
    if screen.skipped and not skip:
        raise ConflictError(
            f"robot {m.robot_id}'s stored map (version {m.version}) has {screen.summary()} outside the "
            f"declared bounds (first: {screen.first}); they were stored before these bounds held. Export "
            "with out_of_bounds=skip to leave them out, or have the robot send a new snapshot.",
            skipped=screen.skipped,
        )
    try:
        return _write(screen.kept, fmt, resolution_m), screen.skipped
    except (InvalidInputError, ExportError) as exc:
        raise ConflictError(
            f"robot {m.robot_id}'s stored map (version {m.version}) cannot be written as {fmt}: {exc}"
        ) from None


@router.get(
    "/export",
    response_class=Response,
    responses={200: {"content": {media: {} for media in _MEDIA_TYPES.values()}}},
    description=(
        "The latest map as a file to download (`version`: that version, e.g. the YAML of the PGM just "
        "fetched, whose version the `X-Map-Version` header and the file name give). 409 when an occupancy "
        "map is asked of a map without walls, when the stored map has items outside the declared bounds "
        "(unless `out_of_bounds=skip`), or when the version asked for is no longer held (with "
        "`current_version`); 422 when the resolution would make a grid of more than 16 M cells. "
        + BOUNDED_DOC
    ),
)
async def export_map(
    robot_id: DbIdPath,
    who: RobotAccess,
    state: StateDep,
    fmt: Annotated[
        _ExportFormat,
        Query(
            alias="format",
            description="geojson, svg, dxf, mcap (ROS 2 messages, as `linemap map --mcap` writes), or "
            "pgm / yaml (a ROS map_server map).",
        ),
    ] = "geojson",
    resolution: Annotated[
        float, Query(gt=0.0, le=10.0, description="Metres per pixel of the pgm / yaml occupancy map.")
    ] = 0.05,
    out_of_bounds: Annotated[
        Literal["refuse", "skip"],
        Query(description="Stored items outside the declared bounds: refuse (409) or skip them."),
    ] = "refuse",
    version: VersionQuery = None,
    session: SessionQuery = None,
) -> Response:
    """The latest map as a file to download (``version``: that version, e.g. the YAML of the PGM just
    fetched, whose version the ``X-Map-Version`` header and the file name give). 409 when an occupancy
    map is asked of a map without walls, when the stored map has items outside the declared bounds
    (unless ``out_of_bounds=skip``), or when the version asked for is no longer held (with
    ``current_version``); 422 when the resolution would make a grid of more than 16 M cells."""
    m = await run_in_threadpool(read_held, state, robot_id, None, version, session)
    extent_m = state.settings.world_extent_m
    body, skipped = await run_in_threadpool(_export, m, fmt, resolution, extent_m, out_of_bounds == "skip")
    headers = {
        "Content-Disposition": f'attachment; filename="{_export_name(m, fmt, resolution)}"',
        "X-Map-Version": str(m.version),
    }
    if skipped:
        headers["X-Map-Skipped"] = ", ".join(f"{k}={n}" for k, n in skipped.items())
    return Response(body, media_type=_MEDIA_TYPES[fmt], headers=headers)
