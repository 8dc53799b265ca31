"""Per-robot upload quotas: token buckets on requests and on bytes, so one robot cannot take the server's
time from the others (docs/reliability/load.md).

A bucket holds up to ``burst`` tokens and refills at ``rate_per_s``; a request costs one request token and
its body length in byte tokens, and passes only when both buckets hold enough (then both are charged). A
refused request is charged nothing and is told when it would pass (``Retry-After``).

The buckets live in this process's memory: with N server processes behind one address, a robot that
spreads its requests over them gets up to N times its quota. That bounds what one robot costs each
process, which is what the quota protects.

All methods must be called from the event loop's thread (no locking). O(1) per check; memory O(robots).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

from server.settings import Settings

__all__ = ["TokenBucket", "UploadQuota"]


@dataclass(slots=True)
class TokenBucket:
    """``burst`` tokens at most, refilled at ``rate_per_s`` (continuous). Starts full."""

    rate_per_s: float
    burst: float
    tokens: float = field(default=-1.0)
    at_s: float = 0.0

    def __post_init__(self) -> None:
        if self.tokens < 0:
            self.tokens = self.burst

    def refill(self, now_s: float) -> None:
        self.tokens = min(self.burst, self.tokens + max(0.0, now_s - self.at_s) * self.rate_per_s)
        self.at_s = now_s

    def wait_s(self, cost: float) -> float:
        """Seconds until ``cost`` tokens are there (0 when they are now); call :meth:`refill` first.
        ``cost`` above ``burst`` never passes: ``inf``."""
        if cost > self.burst:
            return float("inf")
        return max(0.0, (cost - self.tokens) / self.rate_per_s)


class UploadQuota:
    """The request and byte buckets of each robot (created full on a robot's first upload)."""

    def __init__(
        self,
        requests_per_s: float,
        burst_requests: float,
        bytes_per_s: float,
        burst_bytes: float,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._rates = (requests_per_s, burst_requests, bytes_per_s, burst_bytes)
        self._clock = clock
        self._buckets: dict[int, tuple[TokenBucket, TokenBucket]] = {}

    @classmethod
    def from_settings(cls, s: Settings) -> UploadQuota:
        rates = (s.upload_requests_per_s, s.upload_burst_requests, s.upload_bytes_per_s, s.upload_burst_bytes)
        return cls(*rates)

    def _pair(self, robot_id: int, now_s: float) -> tuple[TokenBucket, TokenBucket]:
        pair = self._buckets.get(robot_id)
        if pair is None:
            rps, burst_r, bps, burst_b = self._rates
            pair = (TokenBucket(rps, burst_r, at_s=now_s), TokenBucket(bps, burst_b, at_s=now_s))
            self._buckets[robot_id] = pair
        return pair

    def take(self, robot_id: int, n_bytes: int) -> float | None:
        """Charge one request of ``n_bytes`` to ``robot_id``: ``None`` when it passes, else the seconds to
        wait before it would (nothing is charged then)."""
        now = self._clock()
        requests, data = self._pair(robot_id, now)
        requests.refill(now)
        data.refill(now)
        wait = max(requests.wait_s(1.0), data.wait_s(float(n_bytes)))
        if wait > 0.0:
            return wait
        requests.tokens -= 1.0
        data.tokens -= n_bytes
        return None

    def limits(self) -> str:
        """The quota in words (for the 429's message)."""
        rps, burst_r, bps, burst_b = self._rates
        return f"{rps:g} uploads/s (burst {burst_r:g}) and {bps:g} bytes/s (burst {burst_b:g}) per robot"
