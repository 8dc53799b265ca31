"""Supervised threads: a loop that dies from an unexpected exception is restarted after a backoff and
reported (logged with its traceback, and handed to ``on_death`` which the agent turns into its status'
``last_error``), never silently gone. See docs/reliability/agent.md.

A loop that returns has finished (the agent is stopping) and is not restarted; one that raises one of
``fatal`` ends the supervision and the error is kept in :attr:`Supervised.fatal_error` for the owner.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from robot_agent.link import Backoff

__all__ = ["Supervised", "run_supervised", "supervise"]

log = logging.getLogger(__name__)


@dataclass
class Supervised:
    """One supervised loop's thread and what happened to it: ``restarts`` (deaths survived) and
    ``fatal_error`` (the error that ended it, if a fatal one)."""

    name: str
    thread: threading.Thread | None = None
    restarts: int = 0
    fatal_error: BaseException | None = None
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def join(self, timeout_s: float | None = None) -> None:
        if self.thread is not None:
            self.thread.join(timeout_s)

    def is_alive(self) -> bool:
        return self.thread is not None and self.thread.is_alive()


def run_supervised(
    sup: Supervised,
    loop: Callable[[threading.Event], None],
    stop: threading.Event,
    on_death: Callable[[str, BaseException], None],
    *,
    retry_base_s: float = 0.5,
    retry_cap_s: float = 30.0,
    fatal: tuple[type[BaseException], ...] = (),
) -> None:
    """Run ``loop(stop)`` on the calling thread until it returns or ``stop`` is set; restart it after a
    jittered exponential backoff whenever it raises (``fatal`` exceptions excepted: kept and re-raised).
    The backoff starts again from ``retry_base_s`` once a run lasted longer than ``retry_cap_s``."""
    backoff = Backoff(retry_base_s, retry_cap_s)
    while True:
        started_s = time.monotonic()
        try:
            loop(stop)
            return
        except fatal as exc:
            sup.fatal_error = exc
            raise
        except Exception as exc:  # a bug or an unforeseen answer: report it and start the loop again
            with sup._lock:
                sup.restarts += 1
            log.exception("thread %s died (restart %d)", sup.name, sup.restarts)
            try:
                on_death(sup.name, exc)
            except Exception:  # the report must not take the supervisor down with it
                log.exception("reporting the death of thread %s failed", sup.name)
        if time.monotonic() - started_s > retry_cap_s:
            backoff.reset()  # it ran well for a while: this death is not part of a crash loop
        if stop.wait(backoff.next_delay()):
            return


def supervise(
    name: str,
    loop: Callable[[threading.Event], None],
    stop: threading.Event,
    on_death: Callable[[str, BaseException], None],
    *,
    retry_base_s: float = 0.5,
    retry_cap_s: float = 30.0,
    fatal: tuple[type[BaseException], ...] = (),
) -> Supervised:
    """Start ``loop`` on a daemon thread named ``name`` under :func:`run_supervised`; return its handle. A
    ``fatal`` error ends the thread: it is kept in :attr:`Supervised.fatal_error`, logged, and ``stop`` is
    set, so the owner stops and reports it."""
    sup = Supervised(name)

    def body() -> None:
        try:
            run_supervised(
                sup, loop, stop, on_death, retry_base_s=retry_base_s, retry_cap_s=retry_cap_s, fatal=fatal
            )
        except fatal as exc:
            log.error("thread %s stopped the agent: %s", name, exc)
            stop.set()

    sup.thread = threading.Thread(target=body, name=name, daemon=True)
    sup.thread.start()
    return sup
