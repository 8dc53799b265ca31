"""Wall-clock timing of a callable: medians and p99 over repeated runs after a warm-up."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["Timing", "time_call"]


@dataclass(frozen=True, slots=True)
class Timing:
    """Milliseconds per call over ``runs`` timed calls."""

    median_ms: float
    p99_ms: float
    runs: int

    def as_dict(self) -> dict[str, float | int]:
        """JSON-compatible figures."""
        return {"median_ms": self.median_ms, "p99_ms": self.p99_ms, "runs": self.runs}


def time_call(fn: Callable[[], Any], *, runs: int, warmup: int = 2, budget_s: float | None = None) -> Timing:
    """Time ``fn()`` ``runs`` times after ``warmup`` untimed calls (numba compiles on the first call).

    ``budget_s`` stops early once that much time was spent timing (at least 3 runs are kept).
    """
    for _ in range(warmup):
        fn()
    samples: list[float] = []
    spent = 0.0
    for _ in range(runs):
        start = time.perf_counter()
        fn()
        elapsed = time.perf_counter() - start
        samples.append(elapsed)
        spent += elapsed
        if budget_s is not None and spent > budget_s and len(samples) >= 3:
            break
    arr = np.asarray(samples) * 1e3
    return Timing(float(np.median(arr)), float(np.percentile(arr, 99)), len(samples))
