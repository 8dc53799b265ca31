"""The events of one live-map stream (``GET /robots/{id}/maps/stream``, :mod:`server.routers.maps`): every
version of the robot's map, in order, as a ``delta`` where the viewer can follow delta by delta and as a
``snapshot`` (the whole map) where it cannot.

A viewer is at version ``last`` (the ``id`` of the last event it got; ``Last-Event-ID`` when a browser
reconnects, to this process or another). What wakes the stream:

- an upload to this process: its delta is sent as is when its base is ``last`` (no database read);
- a notice from another process (:class:`server.notices.Notice`), an upload whose base is not ``last``, or
  :data:`server.hub.OVERFLOW` (the viewer fell behind, or the notice listener reconnected): the stream
  catches up from the database: the deltas after ``last`` from the delta log (:mod:`server.maplog`), and
  a snapshot if the log does not reach back to ``last`` or holds a snapshot upload on the way;
- the fallback re-read every ``poll_recheck_s``: the same catch-up when the robot's version moved.

The credential is re-checked every ``AUTH_RECHECK_S``; a comment line every ``KEEPALIVE_S`` of silence
keeps proxies from closing the stream.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator, Callable
from typing import Any

from fastapi import Request
from fastapi.concurrency import run_in_threadpool

from server.deps import AppState, still_valid
from server.hub import OVERFLOW
from server.maplog import LoggedUpload, chain_from, read_after
from server.mapread import map_version
from server.notices import Notice
from server.schemas import MapOut

__all__ = ["AUTH_RECHECK_S", "KEEPALIVE_S", "map_events", "read_log", "sse"]

KEEPALIVE_S = 15.0
#: How often an open stream re-checks its credential (s): with answers at most 0.5 s old
#: (server.deps.STILL_VALID_MAX_AGE_S), a revocation ends it within 0.75 s plus one database read.
AUTH_RECHECK_S = 0.25

ReadMap = Callable[[AppState, int, int | None], MapOut]


def sse(event: str, data: Any, version: int) -> bytes:
    """One server-sent event; ``data`` a map (encoded by pydantic: a non-finite value stored by an older
    server becomes null, valid JSON the page can skip, where json.dumps would write Infinity and the
    browser's JSON.parse throw), JSON text already encoded, or a JSON-able object."""
    if isinstance(data, MapOut):
        text = data.model_dump_json()
    elif isinstance(data, str):
        text = data
    else:
        text = json.dumps(data, separators=(",", ":"))
    return f"event: {event}\nid: {version}\ndata: {text}\n\n".encode()


Current = tuple[str | None, int]  # the robot's (map session, map version)


def _logged(state: AppState, robot_id: int, after: int) -> tuple[Current, list[LoggedUpload]]:
    """((the robot's map session, its version) now, its logged uploads above ``after``): one short read.
    The log holds the current session's uploads only (:func:`server.maplog.clear`)."""
    with state.db.read() as s:
        return map_version(s, robot_id), read_after(s, robot_id, after)


#: Reads of the log in flight, shared by the streams one notice woke at the same version: (app state,
#: robot, after, the notice's version) -> the read. Every stream of a process runs on its event loop.
_shared: dict[tuple[int, int, int, int], asyncio.Future[tuple[Current, list[LoggedUpload]]]] = {}


async def read_log(
    state: AppState, robot_id: int, after: int, notice: int | None
) -> tuple[Current, list[LoggedUpload]]:
    """:func:`_logged` off the event loop. Woken by a notice, a stream joins a read that another stream
    woken by the same notice began (it began after that notice, so it sees that version): N viewers of a
    robot on a process cost one read per notice, not N."""
    if notice is None:
        return await run_in_threadpool(_logged, state, robot_id, after)
    key = (id(state), robot_id, after, notice)
    read = _shared.get(key)
    if read is None:
        read = asyncio.ensure_future(run_in_threadpool(_logged, state, robot_id, after))
        _shared[key] = read
        read.add_done_callback(lambda done: _forget(key, done))
    return await asyncio.shield(read)  # a viewer that leaves does not cancel the others' read


def _forget(key: tuple[int, int, int, int], read: asyncio.Future[Any]) -> None:
    _shared.pop(key, None)
    if not read.cancelled():
        read.exception()  # retrieved here too: every stream that wanted it may have left


async def map_events(
    request: Request,
    state: AppState,
    robot_id: int,
    trajectory: int | None,
    last_event_id: int | None,
    read_map: ReadMap,
) -> AsyncIterator[bytes]:
    """The stream's bytes (module docstring); ``read_map(state, robot_id, trajectory)`` reads the whole
    current map. Ends when the client leaves or its credential stops working."""
    loop = asyncio.get_running_loop()
    recheck = state.settings.poll_recheck_s
    last = -1
    session: str | None = None  # the map session of what the viewer holds (known once sent a snapshot)
    known = False

    async def catch_up(notice: int | None = None) -> AsyncIterator[bytes]:
        """The deltas after ``last`` from the log, then a snapshot if they do not reach the current map
        or the map is another session's; ``notice``: the version of the notice that woke the stream."""
        nonlocal last, session, known
        start, current = last, -1
        if last >= 0:  # (a new viewer gets the whole map: no log to read)
            (now_session, current), logged = await read_log(state, robot_id, last, notice)
            if known and now_session != session:
                last = -1  # a new map (mapping session): never continue the old one with its deltas
            else:
                for entry in chain_from(last, logged):
                    yield sse("delta", entry.body, entry.version)
                    last = entry.version
        # Behind the map still (the log does not reach back, or a snapshot upload is on the way), or at a
        # version the map never had (a Last-Event-ID from elsewhere): the whole map. (The log may also run
        # past `current`: uploads committed between the two reads.)
        if last < 0 or last < current or (last > current and last == start):
            snap = await run_in_threadpool(read_map, state, robot_id, trajectory)
            yield sse("snapshot", snap, snap.version)
            last, session, known = snap.version, snap.map_session, True

    with state.hub.subscribe(f"maps:{robot_id}") as queue:
        if last_event_id is not None:
            last = last_event_id
        async for chunk in catch_up():
            yield chunk
        quiet_since = authed_at = reread_at = loop.time()
        while True:
            if loop.time() - authed_at >= AUTH_RECHECK_S:
                if not await still_valid(request, state):
                    return  # the credential was revoked: the stream ends
                authed_at = loop.time()
            try:
                item = await asyncio.wait_for(queue.get(), timeout=min(recheck, AUTH_RECHECK_S))
            except TimeoutError:
                if await request.is_disconnected():
                    return
                if loop.time() - reread_at < recheck:
                    continue
                reread_at = loop.time()
                now_session, now = await run_in_threadpool(_version, state, robot_id)
                if now != last or (known and now_session != session):  # a notice was missed
                    item = OVERFLOW
                elif loop.time() - quiet_since >= KEEPALIVE_S:
                    quiet_since = loop.time()
                    yield b": keepalive\n\n"
                    continue
                else:
                    continue
            same = not isinstance(item, LoggedUpload) or item.session == session
            if isinstance(item, (Notice, LoggedUpload)) and item.version <= last and same:
                continue  # an upload this stream has sent already (a new session's is caught by the re-read)
            follows = isinstance(item, LoggedUpload) and item.base_version == last and same
            if follows and isinstance(item, LoggedUpload) and item.body is not None:
                yield sse("delta", item.body, item.version)  # an upload to this process: no read
                last = item.version
            else:  # a notice, a snapshot upload, a delta out of step, or OVERFLOW
                async for chunk in catch_up(item.version if isinstance(item, Notice) else None):
                    yield chunk
            quiet_since = loop.time()


def _version(state: AppState, robot_id: int) -> Current:
    with state.db.read() as s:
        return map_version(s, robot_id)
