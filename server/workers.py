"""``linemap server --workers N``: N server processes on one listening socket (PostgreSQL only).

The parent binds the socket, then starts N worker processes (``spawn``: each a fresh interpreter) that
each build the app (the database is migrated by the parent first) and serve it with the same uvicorn
server as one process does (:func:`server_class`: SIGINT/SIGTERM also end its long-polls and streams at
once). The kernel spreads connections over the workers; they share nothing but the database, and wake
each other's waiters through it (:mod:`server.hub`, :mod:`server.pglisten`).

The parent restarts a worker that dies, stops everything when one could not start (exit code
:data:`WORKER_START_FAILED`), and on SIGINT/SIGTERM asks every worker to stop (SIGTERM) and waits for
them.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import signal
import socket
import threading
from typing import Any

__all__ = ["WORKER_START_FAILED", "serve_workers", "server_class"]

log = logging.getLogger(__name__)

#: A worker's exit code when it could not serve (the app or the socket failed).
WORKER_START_FAILED = 3
#: How long the parent waits for its workers to stop, beyond uvicorn's graceful timeout (s).
_STOP_MARGIN_S = 10.0


def server_class() -> Any:
    """uvicorn's server whose exit handler (SIGINT, SIGTERM) also ends the app's long-polls and streams
    (:mod:`server.shutdown`), so Ctrl-C stops at once, cleanly, instead of cancelling them after the
    graceful timeout with a traceback each."""
    import uvicorn

    from server.shutdown import ShutdownSignal

    class Server(uvicorn.Server):
        def __init__(self, config: uvicorn.Config, stopping: ShutdownSignal) -> None:
            super().__init__(config)
            self.stopping = stopping

        def handle_exit(self, sig: int, frame: object) -> None:
            self.stopping.set()
            super().handle_exit(sig, frame)  # type: ignore[arg-type]

    return Server


def _worker(database_url: str, sock: socket.socket, config: dict[str, Any]) -> None:
    """One worker process: build the app on the (migrated) database and serve it on ``sock``."""
    import gc
    import sys

    import uvicorn

    from server.app import create_app
    from server.settings import Settings

    app = create_app(Settings(database_url=database_url), migrate=False)
    gc.collect()
    gc.freeze()  # as one process does (server.cli): the loaded libraries leave the collector's sight
    server = server_class()(uvicorn.Config(app, **config), app.state.shutdown)
    with contextlib.suppress(KeyboardInterrupt):
        server.run(sockets=[sock])
    if not server.started:
        sys.exit(WORKER_START_FAILED)


def serve_workers(database_url: str, host: str, port: int, workers: int, config: dict[str, Any]) -> int:
    """Serve with ``workers`` processes until SIGINT/SIGTERM; the exit code (0, or
    :data:`WORKER_START_FAILED` when the socket could not be bound or a worker could not start).
    ``config``: keyword arguments of ``uvicorn.Config`` for each worker."""
    import uvicorn

    try:
        bind = uvicorn.Config("server.app:create_app", host=host, port=port, log_level="warning")
        sock = bind.bind_socket()
    except SystemExit:  # uvicorn logged why (e.g. the address is in use)
        return WORKER_START_FAILED
    multiprocessing.allow_connection_pickling()
    spawn = multiprocessing.get_context("spawn")
    stop = threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}

    def start() -> multiprocessing.process.BaseProcess:
        proc = spawn.Process(target=_worker, args=(database_url, sock, config), name="linemap-worker")
        proc.start()
        return proc

    procs = [start() for _ in range(workers)]
    code = 0
    try:
        while not stop.wait(0.5):
            for i, proc in enumerate(procs):
                if proc.is_alive():
                    continue
                if proc.exitcode == WORKER_START_FAILED:
                    log.error("a worker could not start (see its message above): stopping the server")
                    code = WORKER_START_FAILED
                    stop.set()
                    break
                log.warning("worker %s exited (code %s): starting another", proc.pid, proc.exitcode)
                procs[i] = start()
    finally:
        for proc in procs:
            if proc.is_alive() and proc.pid is not None:
                with contextlib.suppress(ProcessLookupError):
                    proc.terminate()  # SIGTERM: the worker's graceful shutdown
        wait_s = float(config.get("timeout_graceful_shutdown") or 0) + _STOP_MARGIN_S
        for proc in procs:
            proc.join(wait_s)
            if proc.is_alive():
                log.warning("worker %s did not stop within %.0f s: killing it", proc.pid, wait_s)
                proc.kill()
                proc.join()
        sock.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return code
