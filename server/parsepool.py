"""Parse and validate big map uploads in a worker process, so that their CPU time is not the event loop's.

A near-limit upload (4 MB, ~120,000 rows) takes pydantic-core ~0.3-0.6 s, holding the GIL all along: in a
thread it still stalls every other request of the process (measured: docs/reliability/load.md). The
worker returns the big row lists as NumPy arrays (a memory copy to send and receive, where pickled Python
lists cost as much as parsing again) and the rest as it parsed it; :meth:`UploadParser.parse` rebuilds
the :class:`~server.schemas.MapUpload` without validating it again (O(rows) in C: ``ndarray.tolist``).

For a snapshot the worker also reads the robot's stored map (on its own connection, only reading) and
computes the diff from it (:mod:`server.snapdiff`), so that the write transaction applies only what
changed: a near-limit snapshot that repeats the stored map holds SQLite's write lock for milliseconds
instead of the 0.3-0.7 s of deleting and re-inserting ~120,000 rows. A robot's next snapshot is diffed
against the last one parsed here, without reading the map, while that is what is stored
(:func:`_remembered`).

One worker per server process (spawned on first use): big uploads queue for it; each robot's quota
(:mod:`server.quota`) bounds how often one comes.
"""

from __future__ import annotations

import asyncio
import logging
import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any

import numpy as np
from pydantic import ValidationError
from sqlalchemy.engine import make_url

from server.errors import InvalidRequestError
from server.schemas import MapUpload
from server.snapdiff import SnapshotDiff, StoredMap, diff_snapshot, last_rows

__all__ = ["UploadParser", "parse_upload", "read_stored", "validation_problems"]

log = logging.getLogger(__name__)

_ARRAYS = {"segments": (np.float64, 5), "trajectory": (np.float64, 4), "centroids": (np.float64, 2)}


def validation_problems(exc: ValidationError) -> str:
    """Every problem of a refused body, each with where it is (``segments.3.1: ...``)."""
    return "; ".join(
        f"{'.'.join(str(p) for p in e['loc']) or 'body'}: {e['msg']}" for e in exc.errors(include_url=False)
    )


def parse_upload(raw: bytes, robot_id: int, max_walls: int, world_extent_m: float) -> MapUpload:
    """The validated body; :class:`InvalidRequestError` (422) naming every problem, a value outside its
    declared bound (:func:`server.mapbounds.check_upload_bounds`), or the wall cap."""
    from server.mapbounds import check_upload_bounds
    from server.wallcap import check_wall_cap

    try:
        body = MapUpload.model_validate_json(raw)
    except ValidationError as exc:
        raise InvalidRequestError(validation_problems(exc)) from None
    check_upload_bounds(body, world_extent_m)
    check_wall_cap(robot_id, body, max_walls)
    return body


_STORED_SQL = (
    "SELECT map_version FROM robots WHERE id = {p}",
    "SELECT segment_id, x0_m, y0_m, x1_m, y1_m FROM map_segments WHERE robot_id = {p} ORDER BY segment_id",
    "SELECT stamp_s, x_m, y_m, theta_rad FROM trajectory_points WHERE robot_id = {p} ORDER BY id",
)
_ENGINES: dict[str, Any] = {}  # the worker's database, by URL (one connection pool per worker process)


def _engine(db_url: str) -> Any:
    from server.database import Database

    if db_url not in _ENGINES:
        _ENGINES[db_url] = Database(db_url).engine
    return _ENGINES[db_url]


def read_stored(db_url: str, robot_id: int) -> StoredMap | None:
    """The robot's stored map, read on this process's own connection; ``None`` if the robot does not
    exist or its map changed while it was read. Consistent without a snapshot transaction: the version
    is read before and after, and every write of the map raises the version in the same transaction.
    O(walls + poses): ~0.2 s for a near-limit map."""
    engine = _engine(db_url)
    raw = engine.raw_connection()
    try:
        cur = raw.cursor()
        mark = "?" if engine.dialect.paramstyle == "qmark" else "%s"
        version_sql, walls_sql, traj_sql = (q.format(p=mark) for q in _STORED_SQL)
        cur.execute(version_sql, (robot_id,))
        before = cur.fetchone()
        cur.execute(walls_sql, (robot_id,))
        walls = np.array(cur.fetchall(), dtype=np.float64).reshape(-1, 5)
        cur.execute(traj_sql, (robot_id,))
        traj = np.array(cur.fetchall(), dtype=np.float64).reshape(-1, 4)
        cur.execute(version_sql, (robot_id,))
        after = cur.fetchone()
        raw.rollback()
    finally:
        raw.close()
    if before is None or after is None or before[0] != after[0]:
        return None
    ids = walls[:, 0].astype(np.int64)  # segment ids are within 2**53 (server.mapbounds): exact as floats
    return StoredMap(int(before[0]), ids, np.ascontiguousarray(walls[:, 1:5]), traj)


_COUNTS_SQL = (
    "SELECT (SELECT map_version FROM robots WHERE id = {p}), "
    "(SELECT count(*) FROM map_segments WHERE robot_id = {p}), "
    "(SELECT count(*) FROM trajectory_points WHERE robot_id = {p})"
)
#: The worker's last parsed snapshot per (database, robot): what the robot's map holds once that snapshot
#: is written. A robot posting snapshots back to back has its next one diffed against it, without reading
#: the map (~0.2 s of this process's CPU, which competes with the server's other requests on a 2-core
#: machine). At most ``_LAST_MAX`` robots (~5 MB each near the limit).
_LAST: dict[tuple[str, int], StoredMap] = {}
_LAST_MAX = 4


def _remembered(db_url: str, robot_id: int, written: int | None) -> StoredMap | None:
    """The remembered snapshot of the robot if it is what is stored now: the server process wrote it
    (``written``: the version it last wrote from a snapshot this worker parsed) and the stored map is
    still at that version, with as many walls and poses. Else ``None``: read the map."""
    last = _LAST.get((db_url, robot_id))
    if last is None or written is None or last.version != written:
        return None
    engine = _engine(db_url)
    mark = "?" if engine.dialect.paramstyle == "qmark" else "%s"
    raw = engine.raw_connection()
    try:
        cur = raw.cursor()
        cur.execute(_COUNTS_SQL.format(p=mark), (robot_id,) * 3)
        now = tuple(cur.fetchone() or ())
        raw.rollback()
    finally:
        raw.close()
    return last if now == (written, len(last.wall_ids), len(last.trajectory)) else None


def _diff(db_url: str, robot_id: int, fields: dict[str, Any], written: int | None) -> SnapshotDiff | None:
    """The snapshot's diff against the stored map, or ``None`` (then the writer replaces the map whole):
    the database could not be read, or the map moved while it was read. Remembers the snapshot."""
    try:
        stored = _remembered(db_url, robot_id, written) or read_stored(db_url, robot_id)
    except Exception:  # any database trouble: the full replace is always correct
        log.warning("reading robot %d's stored map for a snapshot diff failed", robot_id, exc_info=True)
        stored = None
    ids, walls = last_rows(fields["segments"])
    _LAST.pop((db_url, robot_id), None)
    _LAST[(db_url, robot_id)] = StoredMap(fields["version"], ids, walls, fields["trajectory"])
    while len(_LAST) > _LAST_MAX:
        del _LAST[next(iter(_LAST))]  # the least recently parsed robot
    return None if stored is None else diff_snapshot(stored, fields["segments"], fields["trajectory"])


def _parse_packed(
    raw: bytes,
    robot_id: int,
    max_walls: int,
    world_extent_m: float,
    db_url: str | None = None,
    written: int | None = None,
) -> tuple[str, Any, Any]:
    """In the worker: ``("ok", fields, diff)`` with the row lists as arrays and, for a snapshot when
    ``db_url`` is given, its :class:`SnapshotDiff` (or ``None``; ``written``: see :func:`_remembered`); or
    ``("error", detail, extra)`` (the error's fields, not the exception: its extras would not survive
    pickling)."""
    try:
        body = parse_upload(raw, robot_id, max_walls, world_extent_m)
    except InvalidRequestError as exc:
        return "error", exc.detail, exc.extra
    fields: dict[str, Any] = {name: getattr(body, name) for name in MapUpload.model_fields}
    for name, (dtype, width) in _ARRAYS.items():
        fields[name] = np.asarray(fields[name], dtype=dtype).reshape(-1, width)
    fields["removed"] = np.asarray(fields["removed"], dtype=np.int64)
    snapshot = db_url is not None and body.base_version is None
    diff = _diff(db_url, robot_id, fields, written) if db_url is not None and snapshot else None
    return "ok", fields, diff


def _file_database(db_url: str | None) -> str | None:
    """``db_url`` if another process can open the same database (not an in-memory SQLite one)."""
    if db_url is None:
        return None
    url = make_url(db_url) if "://" in db_url else None
    if url is not None and url.get_backend_name() == "sqlite" and url.database in (None, "", ":memory:"):
        return None
    return db_url


def _unpack(fields: dict[str, Any]) -> MapUpload:
    out = dict(fields)
    for name in (*_ARRAYS, "removed"):
        out[name] = fields[name].tolist()
    return MapUpload.model_construct(**out)  # validated in the worker


class UploadParser:
    """The worker process (started lazily, ``spawn``: no copy of this process's threads or sockets)."""

    def __init__(self, db_url: str | None = None) -> None:
        self._pool: ProcessPoolExecutor | None = None
        self._db_url = _file_database(db_url)
        self._written: dict[int, int] = {}  # robot id -> version last written from a snapshot parsed here

    async def parse(
        self, raw: bytes, robot_id: int, max_walls: int, world_extent_m: float
    ) -> tuple[MapUpload, SnapshotDiff | None]:
        """:func:`parse_upload` in the worker; the same result or error, and a snapshot's diff against the
        stored map (``None`` for a delta, or when the database given at construction could not be read)."""
        if self._pool is None:
            self._pool = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"))
        loop = asyncio.get_running_loop()
        try:
            kind, value, extra = await loop.run_in_executor(
                self._pool,
                _parse_packed,
                raw,
                robot_id,
                max_walls,
                world_extent_m,
                self._db_url,
                self._written.pop(robot_id, None),
            )
        except BrokenProcessPool:  # the worker died (killed, out of memory): a new one for the next upload
            log.warning("the upload parser process died; parsing this upload in a thread, restarting it")
            self._pool = None
            return await asyncio.to_thread(parse_upload, raw, robot_id, max_walls, world_extent_m), None
        if kind == "error":
            raise InvalidRequestError(value, **extra)
        return await asyncio.to_thread(_unpack, value), extra

    def wrote(self, robot_id: int, version: int) -> None:
        """The snapshot of ``version`` that :meth:`parse` gave for ``robot_id`` was written (not a
        duplicate): the worker may diff the robot's next snapshot against it without reading the map."""
        self._written[robot_id] = version

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
