"""The agent's ``last_error``: the latest problem, with when it happened, until the robot has been healthy
again for a while (see docs/reliability/agent.md).

Rule: an error is reported (in each status the agent uploads) as ``"<UTC time>: <message>"`` until
``clear_after_s`` have passed on the monotonic clock with no new error *and* at least one upload round
succeeded after that; then the status says ``last_error: null`` and the dashboard shows the robot healthy.
A new error restarts the count. Thread-safe; O(1) per call.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from datetime import UTC, datetime

__all__ = ["AgentStats", "ErrorReport"]


class ErrorReport:
    """The latest error and the healthy time since. ``clock`` (monotonic s) and ``wall`` (Unix s) are for
    tests."""

    def __init__(
        self,
        clear_after_s: float = 60.0,
        clock: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
    ) -> None:
        self.clear_after_s = clear_after_s
        self._clock, self._wall = clock, wall
        self._lock = threading.Lock()
        self._message: str | None = None
        self._at_wall_s = 0.0
        self._at_s = 0.0
        self._good_rounds = 0

    def report(self, message: str | None) -> None:
        """Note ``message`` as the latest error (None clears it at once)."""
        with self._lock:
            self._message = message
            self._at_s, self._at_wall_s, self._good_rounds = self._clock(), self._wall(), 0

    def healthy_round(self) -> None:
        """One upload round succeeded (the server has heard from the robot since the error)."""
        with self._lock:
            self._good_rounds += 1
            if (
                self._message is not None
                and self._good_rounds >= 2  # the round that carried the error, then one more
                and self._clock() - self._at_s >= self.clear_after_s
            ):
                self._message = None

    @property
    def message(self) -> str | None:
        """The latest error's text while it is reported, else None."""
        with self._lock:
            return self._message

    def status(self) -> str | None:
        """What the status' ``last_error`` says: ``"2026-12-02T10:00:00Z: <message>"`` or None."""
        with self._lock:
            if self._message is None:
                return None
            at = datetime.fromtimestamp(self._at_wall_s, UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
            return f"{at}: {self._message}"


class AgentStats:
    """Counters of one agent process. ``last_error`` reads and writes the :class:`ErrorReport`."""

    def __init__(self, errors: ErrorReport | None = None) -> None:
        self.steps = 0
        self.swaps_ms: list[float] = []
        self.rollbacks = 0
        self.errors = errors or ErrorReport()

    @property
    def last_error(self) -> str | None:
        return self.errors.message

    @last_error.setter
    def last_error(self, message: str | None) -> None:
        self.errors.report(message)
