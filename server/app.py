"""The FastAPI application: routers under ``/api/v1``, error translation, the request-size limit (413) and
the failed-authentication limit (429, :mod:`server.limiter`, applied by :mod:`server.authguard`).

``create_app(settings)`` migrates the database to the newest schema (Alembic) unless told not to, and
returns the app; ``linemap server`` serves it with uvicorn.
"""

from __future__ import annotations

import asyncio
import functools
import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

from fastapi import APIRouter, Depends, FastAPI, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from server import apidocs, dashboard
from server.admission import PollAdmission
from server.authguard import AuthFailureLimit, AuthScreen
from server.csrf import OriginGuard
from server.database import Database
from server.deps import SESSION_COOKIE, AppState
from server.errors import RateLimitedError, ServerError, StorageFullError
from server.hub import Hub
from server.limiter import retry_after_header
from server.mediatype import require_media_type
from server.migrate import upgrade
from server.parsepool import UploadParser
from server.pglisten import NoticeListener, psycopg_connector
from server.quota import UploadQuota
from server.rolloutdriver import RolloutDriver, drive_forever
from server.routers import auth, control, kernels, maps, messages, meta, robots, rollouts
from server.settings import Settings
from server.shutdown import DisconnectOnShutdown, ShutdownSignal
from server.writer import WriteBatcher

__all__ = ["API_PREFIX", "ROUTERS", "create_app"]

log = logging.getLogger(__name__)
API_PREFIX = "/api/v1"
#: Every router with the prefix it is mounted at (the auth-matrix test walks this list).
ROUTERS: list[tuple[APIRouter, str]] = [
    (meta.router, ""),
    (meta.api_router, API_PREFIX),
    (auth.router, API_PREFIX),
    (robots.router, API_PREFIX),
    (messages.router, API_PREFIX),
    (kernels.router, API_PREFIX),
    (kernels.keys_router, API_PREFIX),
    (maps.router, API_PREFIX),
    (control.router, API_PREFIX),
    (rollouts.router, API_PREFIX),
    (dashboard.router, ""),
]


def create_app(settings: Settings | None = None, *, migrate: bool = True) -> FastAPI:
    """The server application on ``settings.database_url`` (migrated to head first when ``migrate``)."""
    settings = settings or Settings()
    db = Database(settings.database_url, sqlite_max_mb=settings.sqlite_max_mb)
    if migrate:
        upgrade(db.engine)
    # PostgreSQL: writes are announced to the other server processes, whose listeners wake their waiters
    writer = WriteBatcher(db, writers=None if db.is_sqlite else settings.pg_writers)
    state = AppState(settings=settings, db=db, writer=writer, hub=Hub(cross_process=not db.is_sqlite))
    listener = None if db.is_sqlite else NoticeListener(state.hub, psycopg_connector(db.url))

    @asynccontextmanager
    async def lifespan(_app: FastAPI) -> AsyncIterator[None]:
        tasks = [asyncio.create_task(_flush_seen(state)), asyncio.create_task(_checkpoint(state))]
        tasks.append(asyncio.create_task(state.polls.run(settings.poll_recheck_s)))  # server.pollsweep
        tasks.append(asyncio.create_task(drive_forever(driver)))  # rollouts (server.rolloutdriver)
        state.credentials.start(db.read)  # keeps the credentials in use cached (server.credcache)
        if listener is not None:
            listener.start()  # one dedicated connection, LISTEN (server.pglisten)
        yield
        _app.state.shutdown.set()
        for task in tasks:
            task.cancel()
        if listener is not None:
            await listener.stop()
        await run_in_threadpool(state.credentials.stop)
        try:
            await run_in_threadpool(driver.release)
        except Exception:  # the leases then run out by themselves (rollout_lease_s)
            log.exception("could not release this process's rollout leases")
        # the writer threads first (they finish the jobs queued): the flush below writes every robot's row
        # in one transaction, which must not wait for a batch holding some of those rows
        await run_in_threadpool(state.writer.close)
        try:
            await run_in_threadpool(state.flush_seen)
        except StorageFullError as exc:  # the last-seen times are a convenience: stop anyway
            log.warning("robots' last-seen times not recorded at shutdown: %s", exc)
        await run_in_threadpool(parser.close)
        db.dispose()

    app = FastAPI(
        title="linemap server",
        summary="Kernels, robots, control messages and live line maps (docs/design.md §7).",
        version="1",
        lifespan=lifespan,
        dependencies=[Depends(require_media_type)],  # 415 on every route (server.mediatype)
        docs_url=None,  # server.apidocs serves /docs when settings.api_docs says so
        redoc_url=None,
    )
    app.state.linemap = state
    app.state.rollout_driver = driver = RolloutDriver(state)
    app.state.listener = listener
    app.state.shutdown = ShutdownSignal()  # set by ``linemap server`` when it begins to stop
    app.state.upload_quota = UploadQuota.from_settings(settings)  # per process (server.quota)
    app.state.upload_parser = parser = UploadParser(settings.database_url)  # big uploads: a worker process
    app.add_exception_handler(ServerError, _server_error)
    app.add_exception_handler(RequestValidationError, _validation_error)
    app.add_exception_handler(HTTPException, _http_error)
    app.add_exception_handler(Exception, _unexpected_error)
    app.add_middleware(DisconnectOnShutdown, signal=app.state.shutdown)
    app.add_middleware(OriginGuard, trusted_origins=settings.csrf_trusted_origins)  # CSRF (server.csrf)
    app.add_middleware(BodyLimit, max_bytes=settings.max_body_bytes)
    screen = AuthScreen(  # the failed-authentication limit's refusals (server.authguard)
        limiter=state.limiter,
        authenticate=state.authenticate,
        cookie=SESSION_COOKIE,
        api_prefix=API_PREFIX,
        networks=settings.trusted_networks(),
        header=settings.trusted_proxy_header,
    )
    app.add_middleware(  # uploads before a crowd of long-polls opening; polls screened again when let in
        PollAdmission,
        slots=settings.poll_open_slots,
        floor_hz=settings.poll_open_floor_hz,
        screen=screen.refusal,
    )
    # outermost: a blocked source's invalid credential is refused before the body is read
    app.add_middleware(AuthFailureLimit, screen=screen)
    for router, prefix in ROUTERS:
        app.include_router(router, prefix=prefix)
    dashboard.mount(app)
    if settings.api_docs:
        apidocs.mount(app)
    return app


async def _flush_seen(state: AppState, every_s: float = 10.0) -> None:
    """Every few seconds: write robots' last-seen times (one transaction per writer thread, each for the
    robots whose uploads that thread writes: server.writer)."""
    writer = state.writer
    while True:
        await asyncio.sleep(every_s)
        try:
            await asyncio.gather(
                *(
                    writer.submit(functools.partial(state.flush_seen, shard=(k, writer.shards)), key=k)
                    for k in range(writer.shards)
                )
            )
        except StorageFullError as exc:  # said once by the database; retried with the next round
            log.debug("robots' last-seen times not recorded: %s", exc)
        except Exception:  # retried with the next round; never kill the task
            log.exception("could not record robots' last-seen times")


async def _checkpoint(state: AppState, every_s: float = 2.0) -> None:
    """Every couple of seconds: fold the SQLite write-ahead log into the database and reset it
    (:meth:`Database.checkpoint`; at 200 uploads/s the log grows ~25 MB/s, so a short period keeps the
    file and each reset small)."""
    if not state.db.is_sqlite:
        return
    while True:
        await asyncio.sleep(every_s)
        try:
            await run_in_threadpool(state.db.checkpoint)
        except Exception:  # retried with the next round; never kill the task
            log.exception("could not checkpoint the database")


async def _server_error(_request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, ServerError)
    body: dict[str, Any] = {"error": exc.code, "detail": exc.detail, **exc.extra}
    headers = {"WWW-Authenticate": "Bearer"} if exc.status == 401 else None
    if isinstance(exc, RateLimitedError):
        headers = {"Retry-After": retry_after_header(exc.retry_after_s)}
    return JSONResponse(body, status_code=exc.status, headers=headers)


_CODES = {
    400: "bad_request",
    401: "unauthenticated",
    403: "forbidden",
    404: "not_found",
    405: "method_not_allowed",
    413: "too_large",
    415: "unsupported_media_type",
}


async def _http_error(_request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, HTTPException)
    if isinstance(exc, _TooLarge):
        limit = _request.app.state.linemap.settings.max_body_bytes
        detail = f"request body of {exc.size}+ bytes; the limit is {limit}"
    else:
        detail = str(exc.detail)
    return JSONResponse(
        {"error": _CODES.get(exc.status_code, "http_error"), "detail": detail},
        status_code=exc.status_code,
        headers=exc.headers,
    )


async def _validation_error(_request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RequestValidationError)
    errors = _jsonable(exc.errors())
    problems = []
    for err in errors:
        where = ".".join(str(p) for p in err["loc"] if p != "body")
        problems.append(f"{where}: {err['msg'] or 'invalid'}")
    return JSONResponse(
        {"error": "invalid", "detail": "; ".join(problems), "errors": errors}, status_code=422
    )


def _jsonable(errors: Any) -> list[dict[str, Any]]:
    """The validation errors, each once: a path parameter read by the route and by a dependency (the
    robot id) is validated twice and would be reported twice."""
    out: list[dict[str, Any]] = []
    for e in errors:
        item = {"loc": list(e.get("loc", ())), "msg": str(e.get("msg", "")), "type": str(e.get("type", ""))}
        if item not in out:
            out.append(item)
    return out


async def _unexpected_error(request: Request, exc: Exception) -> JSONResponse:
    log.exception("unexpected error on %s %s", request.method, request.url.path)
    return JSONResponse(
        {"error": "internal", "detail": f"internal server error ({type(exc).__name__}); see the server log"},
        status_code=500,
    )


class BodyLimit:
    """Refuse request bodies above ``max_bytes`` with 413, by Content-Length or while streaming."""

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        declared = dict(scope["headers"]).get(b"content-length")
        if declared is not None and declared.isdigit() and int(declared) > self.max_bytes:
            await self._refuse(send, int(declared))
            return
        seen = 0
        started = False

        async def limited_receive() -> Message:
            nonlocal seen
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > self.max_bytes:
                    raise _TooLarge(seen)
            return message

        async def tracking_send(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, limited_receive, tracking_send)
        except _TooLarge as exc:
            if not started:
                await self._refuse(send, exc.size)

    async def _refuse(self, send: Send, size: int) -> None:
        body = JSONResponse(
            {"error": "too_large", "detail": f"request body of {size}+ bytes; the limit is {self.max_bytes}"},
            status_code=413,
        )
        await send({"type": "http.response.start", "status": 413, "headers": body.raw_headers})
        await send({"type": "http.response.body", "body": body.body})


class _TooLarge(HTTPException):
    """Raised from ``receive`` mid-body; an HTTPException so FastAPI's body parsing passes it through."""

    def __init__(self, size: int) -> None:
        super().__init__(413, f"request body of {size}+ bytes is over the limit")
        self.size = size
