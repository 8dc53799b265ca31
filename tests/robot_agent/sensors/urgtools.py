"""Helpers of the URG-04LX tests: tell which emulated scan came back through the driver (by its ranges
rounded to mm, as the sensor sends them), and consume a driver's stream in a thread."""

from __future__ import annotations

import contextlib
import queue
import threading
import time
from collections.abc import Callable, Iterator, Sequence

import numpy as np

from robot_agent.sensors.urg import UrgDriver
from shared.types import Scan

SAFETY_S = 30.0  # bound for waits that must not hang a broken test (never a timing assertion)


def mm(scan: Scan) -> np.ndarray:
    """The scan's ranges as the sensor sends them: integer mm, -1 for no return."""
    r = np.asarray(scan.ranges_m)
    whole = np.rint(np.where(np.isfinite(r), r, -1.0) * 1000.0)
    return np.where((whole >= 20) & (whole <= 5600), whole, -1).astype(np.int64)


class ScanIndex:
    """Which of ``scans`` a received scan is (its mm ranges must match exactly)."""

    def __init__(self, scans: Sequence[Scan]) -> None:
        self._by_key: dict[bytes, int] = {}
        for i, s in enumerate(scans):
            self._by_key.setdefault(mm(s).tobytes(), i)

    def __call__(self, scan: Scan) -> int:
        key = mm(scan).tobytes()
        assert key in self._by_key, "a received scan matches none of the emulated scans to the mm"
        return self._by_key[key]


class Consumer:
    """Runs ``driver.scans()`` in a thread and queues what arrives (so the test thread can fault the
    emulator meanwhile). ``get()`` waits at most SAFETY_S."""

    def __init__(self, driver: UrgDriver, **kwargs: int) -> None:
        self.driver = driver
        self.q: queue.Queue[Scan | BaseException | None] = queue.Queue()
        self.thread = threading.Thread(target=self._run, kwargs=kwargs, daemon=True)
        self.thread.start()

    def _run(self, **kwargs: int) -> None:
        try:
            for scan in self.driver.scans(**kwargs):
                self.q.put(scan)
        except BaseException as exc:  # handed to the test thread
            self.q.put(exc)
        self.q.put(None)

    def get(self) -> Scan:
        item = self.q.get(timeout=SAFETY_S)
        if isinstance(item, BaseException):
            raise item
        assert item is not None, "the scan stream ended early"
        return item

    def take(self, n: int) -> list[Scan]:
        return [self.get() for _ in range(n)]

    def close(self) -> None:
        self.driver.stop.set()
        self.thread.join(SAFETY_S)
        assert not self.thread.is_alive(), "the scan stream did not end when stopped"


@contextlib.contextmanager
def consume(driver: UrgDriver, **kwargs: int) -> Iterator[Consumer]:
    """A :class:`Consumer` of ``driver.scans(**kwargs)``, stopped on exit."""
    c = Consumer(driver, **kwargs)
    try:
        yield c
    finally:
        c.close()


def wait_until(what: str, check: Callable[[], bool]) -> None:
    """Poll ``check`` until true (a readiness wait bounded by SAFETY_S, not a timing assertion)."""
    deadline = time.monotonic() + SAFETY_S
    while not check():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.01)
