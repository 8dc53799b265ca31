"""One agent per Robot DB: an exclusive lock on ``<Robot DB>.lock`` held for the agent's lifetime.

Two agents writing one Robot DB would interleave two maps' versions in one outbox. The lock is an
``flock`` on a file beside the database (not the database file: SQLite's own POSIX locks on it must stay
untouched), released by the kernel when the process ends however it ends (kill -9 included), so a stale
lock never keeps a restarted agent out. The file holds the holder's pid, for the error message only.
"""

from __future__ import annotations

import fcntl
import logging
import os
from pathlib import Path

from robot_agent.errors import SupersededError

__all__ = ["RobotDBLock"]

log = logging.getLogger(__name__)


class RobotDBLock:
    """Hold the lock of the Robot DB at ``db_path`` or raise :class:`SupersededError` naming the holder."""

    def __init__(self, db_path: Path | str) -> None:
        self.path = Path(f"{db_path}.lock")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fd: int | None = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(self._fd, 32, 0).decode("ascii", "replace").strip() or "unknown"
            os.close(self._fd)
            self._fd = None
            raise SupersededError(
                f"another agent (pid {holder}) is running on the Robot DB {db_path}: only one agent may use "
                f"a Robot DB (lock file {self.path}); stop it first"
            ) from None
        os.ftruncate(self._fd, 0)
        os.pwrite(self._fd, f"{os.getpid()}\n".encode(), 0)

    def release(self) -> None:
        """Let go of the lock (idempotent)."""
        if self._fd is not None:
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None
