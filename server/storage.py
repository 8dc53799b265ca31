"""Whether the server's database can still grow: a write refused for want of space (a full disk, or the
SQLite size limit ``sqlite_max_mb``) is answered 507 with the reason, and ``/healthz`` fails until a write
succeeds again (space was freed: the robots' next uploads find it).

What counts as a full disk: :func:`shared.diskfull.disk_full_reason` (re-exported here).
"""

from __future__ import annotations

import threading
import time

from shared.diskfull import disk_full_reason

__all__ = ["StorageState", "disk_full_reason"]


class StorageState:
    """The last write's verdict on space: :meth:`problem` is the reason and since when (Unix s) while the
    last write was refused for want of space, else None. Thread-safe."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._problem: tuple[str, float] | None = None

    def failed(self, reason: str) -> None:
        with self._lock:
            if self._problem is None:
                self._problem = (reason, time.time())

    def succeeded(self) -> None:
        if self._problem is not None:
            with self._lock:
                self._problem = None

    def problem(self) -> tuple[str, float] | None:
        with self._lock:
            return self._problem
