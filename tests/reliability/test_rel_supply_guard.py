"""Run-time guard of hot-swapped kernels against garbage (issue 9 item 4): a kernel that passed every
check before it ran and then returns a bad result in service (non-finite values, wrong shapes, wrong type),
hangs or allocates without bound is answered by the kernel it replaced, and the agent is told, so the
garbage never reaches the map and the step completes. The
same through a real agent and server: test_rel_supply_live.py::test_supply_chain_matrix[nan-in-service].
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np
import pytest

from robot_agent.guard import guarded, resident_mb
from shared.kernels import REGISTRY, NoiseResult
from shared.kernels.noise.dbscan import Dbscan
from shared.sim import default_world, simulate_scan
from shared.types import Pose2D


class Nan(Dbscan):
    version = "9.0.1"

    def apply(self, points: Any) -> NoiseResult:
        out = super().apply(points)
        return NoiseResult(out.keep, np.full_like(np.asarray(out.points, float), np.nan), out.labels)


class Shapes(Dbscan):
    version = "9.0.2"

    def apply(self, points: Any) -> NoiseResult:
        return NoiseResult(np.ones(3, dtype=bool), np.zeros((2, 3)), np.zeros(7, dtype=np.intp))


class WrongType(Dbscan):
    version = "9.0.3"

    def apply(self, points: Any) -> Any:
        return [[0.0, 0.0]]


def _points() -> np.ndarray:
    scan = simulate_scan(default_world(), Pose2D(4.5, 2.0, np.pi), np.random.default_rng(3))
    seg = REGISTRY.create("segmentation", "abd-iepf").apply(scan)  # type: ignore[attr-defined]
    return np.asarray(seg.points)


@pytest.mark.parametrize(
    ("cls", "problem"),
    [
        (Nan, "NoiseResult.points has non-finite values"),
        (Shapes, "NoiseResult.keep is bool (3,)"),
        (WrongType, "returned list: expected NoiseResult"),
    ],
)
def test_a_bad_result_is_replaced_by_the_fallback_and_reported(cls: type[Dbscan], problem: str) -> None:
    failures: list[tuple[type[Any], str]] = []
    fallback = Dbscan()
    kernel: Any = guarded(cls, lambda: fallback, lambda c, why: failures.append((c, why)), 1e9)()
    points = _points()
    got = kernel.apply(points)
    want = fallback.apply(points)
    assert np.array_equal(got.points, want.points) and np.array_equal(got.keep, want.keep)
    assert len(failures) == 1 and failures[0][0] is cls
    assert (
        failures[0][1].startswith(f"dbscan {cls.version} returned a bad result: ")
        and problem in failures[0][1]
    )


def test_a_good_result_passes_untouched() -> None:
    failures: list[str] = []
    kernel: Any = guarded(
        Dbscan, lambda: pytest.fail("no fallback needed"), lambda c, why: failures.append(why), 1e9
    )()
    points = _points()
    got = kernel.apply(points)
    assert failures == [] and np.array_equal(got.points, Dbscan().apply(points).points)


# ---------------------------------------------------------------------------------- stuck in service
class _Blocking(Dbscan):
    """Blocks on ``release`` (a hang the test can end), after ``hold`` MB were written, if any."""

    version = "9.0.4"
    release = threading.Event()
    hold_mb = 0
    calls = 0

    def apply(self, points: Any) -> NoiseResult:
        _Blocking.calls += 1
        kept = np.ones(_Blocking.hold_mb * 2**17) if _Blocking.hold_mb else None  # 8-byte floats, written
        _Blocking.release.wait(60)
        del kept
        return super().apply(points)


def _guard(cls: type[Dbscan], **limits: float) -> tuple[Any, Dbscan, list[str], list[str]]:
    """``cls`` guarded with a built-in DBSCAN as its fallback and no time budget: the kernel, the fallback,
    and the lists its failures and stuck reports go to."""
    failures: list[str] = []
    stuck: list[str] = []
    fallback = Dbscan()
    kernel: Any = guarded(
        cls,
        lambda: fallback,
        lambda c, why: failures.append(why),
        1e9,
        on_stuck=lambda c, why: stuck.append(why),
        **limits,
    )()
    return kernel, fallback, failures, stuck


def _stuck_run(hold_mb: int, memory_mb: float, hang_s: float) -> tuple[list[str], list[str], Any, Any]:
    _Blocking.release = threading.Event()
    _Blocking.hold_mb, _Blocking.calls = hold_mb, 0
    kernel, fallback, failures, stuck = _guard(_Blocking, hang_s=hang_s, memory_mb=memory_mb)
    points = _points()
    try:
        first = kernel.apply(points)
        second = kernel.apply(points)  # answered by the fallback: the stuck kernel is not called again
    finally:
        _Blocking.release.set()
    assert _Blocking.calls == 1
    want = fallback.apply(points)
    for got in (first, second):
        assert np.array_equal(got.points, want.points) and np.array_equal(got.keep, want.keep)
    return failures, stuck, first, second


def test_a_call_that_hangs_is_answered_by_the_fallback_and_reported_stuck() -> None:
    failures, stuck, _, _ = _stuck_run(hold_mb=0, memory_mb=1e6, hang_s=0.1)
    assert failures == stuck == ["dbscan 9.0.4 did not return within 0.1 s (hung)"]


@pytest.mark.skipif(resident_mb() is None, reason="needs /proc/self/statm (Linux)")
def test_a_call_that_allocates_past_its_limit_is_stuck_before_it_returns() -> None:
    failures, stuck, _, _ = _stuck_run(hold_mb=200, memory_mb=64, hang_s=60)
    assert len(failures) == 1 and failures == stuck
    assert failures[0].startswith("dbscan 9.0.4 allocated ")
    assert failures[0].endswith(" MB in one call (and counting), over its 64 MB limit")


def test_an_exception_from_the_worker_thread_is_a_failure_not_stuck() -> None:
    class Raises(Dbscan):
        version = "9.0.5"

        def apply(self, points: Any) -> NoiseResult:
            raise ZeroDivisionError("planted")

    kernel, _, failures, stuck = _guard(Raises)
    kernel.apply(_points())
    assert failures == ["dbscan 9.0.5 raised ZeroDivisionError: planted"] and stuck == []


def test_an_idle_worker_thread_ends_and_the_next_call_starts_one(monkeypatch: pytest.MonkeyPatch) -> None:
    from robot_agent import guard

    monkeypatch.setattr(guard, "IDLE_S", 0.05)

    class Fine(Dbscan):
        version = "9.0.6"

    kernel: Any = guarded(Fine, lambda: pytest.fail("no fallback needed"), lambda c, why: None, 1e9)()
    points = _points()

    def workers() -> list[threading.Thread]:
        return [t for t in threading.enumerate() if t.name == "kernel dbscan 9.0.6"]

    kernel.apply(points)
    deadline = threading.Event()
    for _ in range(400):  # poll until the idle thread has ended (readiness wait, up to ~20 s)
        if not workers():
            break
        deadline.wait(0.05)
    assert workers() == [], "the idle worker thread did not end"
    got = kernel.apply(points)  # a new thread takes the call
    assert np.array_equal(got.points, Dbscan().apply(points).points)
