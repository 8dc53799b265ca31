"""A real server on 127.0.0.1 whose brute-force limit is small and whose clock the test steps by hand, so
"blocked for a bounded time" is checked without sleeping. Used by tests/reliability/test_rel_auth_limits.py
(the limit through HTTP), tests/robot_agent/test_link.py (the robot's link seeing the server's 429) and
tests/server/test_limiter.py (the limiter in process)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

from tests.server.live import Live, start_live

LIMIT, WINDOW_S, BLOCK_S = 5, 60.0, 30.0
WRONG = "lmo_not-a-real-token-0000000000000000000000"


class SteppedClock:
    """A monotonic clock the test moves by hand (seconds)."""

    def __init__(self) -> None:
        self.now_s = 1000.0

    def __call__(self) -> float:
        return self.now_s


def start_limited(tmp: Path, clock: SteppedClock) -> Iterator[Live]:
    """A SQLite server allowing ``LIMIT`` failed authentications per source in ``WINDOW_S``, then blocking
    that source's failed attempts for ``BLOCK_S``, timed by ``clock``."""
    for server in start_live(
        "sqlite",
        tmp,
        auth_fail_limit=LIMIT,
        auth_fail_window_s=WINDOW_S,
        auth_block_s=BLOCK_S,
        auth_fail_delay_s=0.01,
    ):
        server.state.limiter.clock = clock
        yield server
