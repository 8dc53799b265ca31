"""Run-time protection for hot-swapped kernels, for as long as they run.

:func:`guarded` subclasses a downloaded kernel class so that each ``apply`` is timed and checked, and a
raised exception never escapes: the call is answered by ``fallback`` (the kernel it replaced) instead, so
the step completes and no scan is lost, and ``on_failure`` is told, after which the agent rolls the kernel
back. A result that fails the stage's result checks (:func:`shared.kernels.conformance.check_result`: type,
shapes, non-finite values; issue 9 item 4) is treated the same way: it never reaches the map. A call
slower than ``budget_ms`` also counts as a failure (its result is still used).

A kernel that passed its dry run can still hang or allocate without bound later, in service. So each call
runs on the kernel's own worker thread while the calling (mapping) thread watches it:

- a call that has not returned after ``hang_s`` seconds is **stuck**;
- a call during which the process's resident memory grew by more than ``memory_mb`` MB is **stuck** too
  (a runaway allocation; read from ``/proc/self/statm`` before the call and every ``WATCH_TICK_S`` while
  it lasts). Memory that other threads allocate meanwhile counts too, so the limit is set well above
  what a step needs (256 MB by default, against a few MB).

A stuck call is answered by ``fallback``, reported to ``on_failure`` and to ``on_stuck``, and the kernel is
never called again in this process. Python cannot stop a thread, so the stuck thread goes on until the
process ends: the agent's CLI restarts itself in place (see :mod:`robot_agent.agent`), which frees it.

Overhead per call: one hand-over to the worker thread and back and one read of ``/proc/self/statm`` (tens
of microseconds together), one ``perf_counter`` pair and one O(N) result check.
"""

from __future__ import annotations

import os
import queue
import threading
import time
from collections.abc import Callable
from typing import Any

from shared.kernels import Kernel, Stage
from shared.kernels.conformance import check_result

__all__ = ["IDLE_S", "WATCH_TICK_S", "guarded", "resident_mb"]

#: How often a running call's memory is read (s).
WATCH_TICK_S = 0.02
#: A kernel's worker thread ends after this long without a call (s).
IDLE_S = 30.0

_PAGE_MB = os.sysconf("SC_PAGE_SIZE") / 2**20 if hasattr(os, "sysconf") else 4096 / 2**20


def resident_mb() -> float | None:
    """This process's resident memory (MB), or None where ``/proc/self/statm`` does not exist."""
    try:
        with open("/proc/self/statm", "rb") as f:
            return int(f.read().split()[1]) * _PAGE_MB
    except (OSError, IndexError, ValueError):
        return None


class _StuckError(Exception):
    """A call did not come back in time, or allocated past its limit (the reason is the message)."""


class _Worker:
    """Runs a kernel's calls, one at a time, on a daemon thread while the caller watches. The thread ends
    after ``IDLE_S`` without a call (a kernel rolled back or replaced leaves no thread behind) and is
    started again by the next call."""

    def __init__(self, label: str) -> None:
        self._label = label
        self._jobs: queue.SimpleQueue[tuple[Callable[[], Any], list[Any], threading.Event]] = (
            queue.SimpleQueue()
        )
        self._lock = threading.Lock()
        self._running = False

    def _loop(self) -> None:
        while True:
            try:
                fn, box, done = self._jobs.get(timeout=IDLE_S)
            except queue.Empty:
                with self._lock:  # a call put under this lock is seen here, or finds no thread running
                    if self._jobs.empty():
                        self._running = False
                        return
                continue
            try:
                box.append((True, fn()))
            except BaseException as exc:  # handed back to the caller, who decides
                box.append((False, exc))
            done.set()

    def _put(self, job: tuple[Callable[[], Any], list[Any], threading.Event]) -> None:
        with self._lock:
            self._jobs.put(job)
            if not self._running:
                self._running = True
                threading.Thread(target=self._loop, name=f"kernel {self._label}", daemon=True).start()

    def call(self, fn: Callable[[], Any], hang_s: float, memory_mb: float) -> Any:
        """``fn()`` on the worker; its result, or its exception re-raised; :class:`_StuckError` if it hangs
        for ``hang_s`` or grows the process by ``memory_mb``."""
        box: list[Any] = []
        done = threading.Event()
        start_mb = resident_mb()
        self._put((fn, box, done))
        deadline = time.monotonic() + hang_s
        while not done.wait(min(WATCH_TICK_S, max(0.0, deadline - time.monotonic()))):
            now_mb = resident_mb()
            if start_mb is not None and now_mb is not None and now_mb - start_mb > memory_mb:
                raise _StuckError(
                    f"allocated {now_mb - start_mb:.0f} MB in one call (and counting), over its "
                    f"{memory_mb:g} MB limit"
                )
            if time.monotonic() >= deadline:
                raise _StuckError(f"did not return within {hang_s:g} s (hung)")
        ok, value = box[0]
        if ok:
            return value
        raise value


def guarded(
    cls: type[Kernel[Any]],
    fallback: Callable[[], Kernel[Any]],
    on_failure: Callable[[type[Kernel[Any]], str], None],
    budget_ms: float,
    *,
    hang_s: float = 5.0,
    memory_mb: float = 256.0,
    on_stuck: Callable[[type[Kernel[Any]], str], None] | None = None,
) -> type[Kernel[Any]]:
    """A subclass of ``cls`` with the same stage, name, version and parameters, guarded as above."""
    base: Any = cls
    state: dict[str, Any] = {"worker": None, "stuck": None}

    def run(fn: Callable[[], Any]) -> Any:
        worker = state["worker"]
        if worker is None:
            worker = state["worker"] = _Worker(f"{cls.name} {cls.version}")
        return worker.call(fn, hang_s, memory_mb)

    class Guarded(base):  # type: ignore[misc]
        def apply(self, *args: Any, **kwargs: Any) -> Any:
            def answer_by_fallback() -> Any:
                return fallback().apply(*args, **kwargs)  # type: ignore[attr-defined]

            if state["stuck"] is not None:  # its thread is still busy: never call it again
                return answer_by_fallback()
            t0 = time.perf_counter()
            try:
                out = run(lambda: super(Guarded, self).apply(*args, **kwargs))
            except _StuckError as exc:
                reason = f"{cls.name} {cls.version} {exc}"
                state["stuck"] = reason
                on_failure(cls, reason)
                if on_stuck is not None:
                    on_stuck(cls, reason)
                return answer_by_fallback()
            except Exception as exc:
                on_failure(cls, f"{cls.name} {cls.version} raised {type(exc).__name__}: {exc}")
                return answer_by_fallback()
            elapsed_ms = (time.perf_counter() - t0) * 1e3
            problems = check_result(cls.stage, out, _n_in(cls.stage, args, kwargs))
            if problems:
                shown = "; ".join(problems[:3])
                on_failure(cls, f"{cls.name} {cls.version} returned a bad result: {shown}"[:500])
                return answer_by_fallback()
            if elapsed_ms > budget_ms:
                on_failure(
                    cls,
                    f"{cls.name} {cls.version} took {elapsed_ms:.1f} ms, over its {budget_ms:g} ms budget",
                )
            return out

    Guarded.__name__ = cls.__name__
    Guarded.__qualname__ = cls.__qualname__
    Guarded.__doc__ = cls.__doc__
    Guarded.__module__ = cls.__module__
    return Guarded


def _n_in(stage: Stage | str, args: tuple[Any, ...], kwargs: dict[str, Any]) -> int:
    """Input points of a call, for the stages whose result checks need it (noise removal, clustering)."""
    if Stage(stage) not in (Stage.NOISE_REMOVAL, Stage.CLUSTERING):
        return 0
    points = args[0] if args else next(iter(kwargs.values()), ())
    try:
        return len(points)
    except TypeError:
        return 0
