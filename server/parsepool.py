"""Parse and validate big map uploads in a worker process, so that their CPU time is not the event loop's.

A near-limit upload (4 MB, ~120,000 rows) takes pydantic-core ~0.3-0.6 s, holding the GIL all along: in a
thread it still stalls every other request of the process (measured: docs/reliability/load.md). The
worker returns the big row lists as NumPy arrays (a memory copy to send and receive, where pickled Python
lists cost as much as parsing again) and the rest as it parsed it; :meth:`UploadParser.parse` rebuilds
the :class:`~server.schemas.MapUpload` without validating it again (O(rows) in C: ``ndarray.tolist``).

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

from server.errors import InvalidRequestError
from server.schemas import MapUpload

__all__ = ["UploadParser", "parse_upload", "validation_problems"]

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
    from server.mapstore import check_wall_cap  # mapstore imports the models: not needed before this

    try:
        body = MapUpload.model_validate_json(raw)
    except ValidationError as exc:
        raise InvalidRequestError(validation_problems(exc)) from None
    check_upload_bounds(body, world_extent_m)
    check_wall_cap(None, robot_id, body, max_walls)
    return body


def _parse_packed(raw: bytes, robot_id: int, max_walls: int, world_extent_m: float) -> tuple[str, Any, Any]:
    """In the worker: ``("ok", fields, None)`` with the row lists as arrays, or ``("error", detail,
    extra)`` (the error's fields, not the exception: its extras would not survive pickling)."""
    try:
        body = parse_upload(raw, robot_id, max_walls, world_extent_m)
    except InvalidRequestError as exc:
        return "error", exc.detail, exc.extra
    fields: dict[str, Any] = {name: getattr(body, name) for name in MapUpload.model_fields}
    for name, (dtype, width) in _ARRAYS.items():
        fields[name] = np.asarray(fields[name], dtype=dtype).reshape(-1, width)
    fields["removed"] = np.asarray(fields["removed"], dtype=np.int64)
    return "ok", fields, None


def _unpack(fields: dict[str, Any]) -> MapUpload:
    out = dict(fields)
    for name in (*_ARRAYS, "removed"):
        out[name] = fields[name].tolist()
    return MapUpload.model_construct(**out)  # validated in the worker


class UploadParser:
    """The worker process (started lazily, ``spawn``: no copy of this process's threads or sockets)."""

    def __init__(self) -> None:
        self._pool: ProcessPoolExecutor | None = None

    async def parse(self, raw: bytes, robot_id: int, max_walls: int, world_extent_m: float) -> MapUpload:
        """:func:`parse_upload` in the worker; the same result or error."""
        if self._pool is None:
            self._pool = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"))
        loop = asyncio.get_running_loop()
        try:
            kind, value, extra = await loop.run_in_executor(
                self._pool, _parse_packed, raw, robot_id, max_walls, world_extent_m
            )
        except BrokenProcessPool:  # the worker died (killed, out of memory): a new one for the next upload
            log.warning("the upload parser process died; parsing this upload in a thread, restarting it")
            self._pool = None
            return await asyncio.to_thread(parse_upload, raw, robot_id, max_walls, world_extent_m)
        if kind == "error":
            raise InvalidRequestError(value, **extra)
        return await asyncio.to_thread(_unpack, value)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
