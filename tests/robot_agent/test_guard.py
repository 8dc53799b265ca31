"""Run-time guard of hot-swapped kernels against garbage (robot_agent/guard.py; docs/reliability/supply.md): a
kernel that passed every check before it ran and then returns a bad result in service (non-finite values,
wrong shapes, wrong type), hangs or allocates without bound is answered by the kernel it replaced, and the
agent is told, so the garbage never reaches the map and the step completes. The same through a real agent and
server: tests/reliability/test_rel_supply_live.py::test_supply_chain_matrix[nan-in-service].
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from robot_agent.guard import guarded
from robot_agent.kernels.dryrun import load_in_worker
from shared.errors import KernelParameterError
from shared.kernels import REGISTRY, NoiseResult
from shared.kernels.noise.dbscan import Dbscan
from shared.sim import default_world, simulate_scan
from shared.types import Pose2D


class Nan(Dbscan):
    version = "9.0.1"

    def apply(self, points: Any, spacing_m: Any = None) -> NoiseResult:
        out = super().apply(points, spacing_m)
        return NoiseResult(out.keep, np.full_like(np.asarray(out.points, float), np.nan), out.labels)


class Shapes(Dbscan):
    version = "9.0.2"

    def apply(self, points: Any, spacing_m: Any = None) -> NoiseResult:
        return NoiseResult(np.ones(3, dtype=bool), np.zeros((2, 3)), np.zeros(7, dtype=np.intp))


class WrongType(Dbscan):
    version = "9.0.3"

    def apply(self, points: Any, spacing_m: Any = None) -> Any:
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


def test_only_calls_over_the_budget_in_a_row_fail_the_kernel() -> None:
    """A call over the budget now and then (a busy moment of the machine) is no failure; ``overruns`` in a
    row are, reported once, the results used all the while."""
    durations_s = iter([0.3, 0.1, 0.3, 0.3, 0.1, 0.3, 0.3, 0.3, 0.3])  # each call's time on the clock
    now = [0.0]

    def clock() -> float:  # a call's start, then its end
        now[0] += next(durations_s) if clock.started else 0.0  # type: ignore[attr-defined]
        clock.started = not clock.started  # type: ignore[attr-defined]
        return now[0]

    clock.started = False  # type: ignore[attr-defined]
    failures: list[str] = []
    kernel: Any = guarded(
        Dbscan,
        lambda: pytest.fail("a slow result is still used"),
        lambda c, why: failures.append(why),
        200.0,
        clock=clock,
    )()
    points = _points()
    for call in range(1, 10):
        assert np.array_equal(kernel.apply(points).points, Dbscan().apply(points).points)
        assert len(failures) == (1 if call >= 8 else 0), (call, failures)
    assert failures[0].startswith("dbscan 1.0.0 took 300.0 ms, over its 200 ms budget (3 calls in a row)")
    with pytest.raises(ValueError, match="overruns=0"):
        guarded(Dbscan, Dbscan, lambda c, why: None, 200.0, overruns=0)


# ---------------------------------------------------------------------------------- stuck in service
# The kernels below run as the agent runs a downloaded kernel: in a confined worker process.


def _remote(version: str, body: str, **limits: float) -> type[Any]:
    """A DBSCAN ``version`` whose ``apply`` is ``body``, loaded in its own worker process."""
    source = (
        "import numpy as np\n"
        "from shared.kernels import NoiseResult\n"
        "from shared.kernels.noise.dbscan import Dbscan\n\n\n"
        f"class Planted(Dbscan):\n    version = '{version}'\n\n"
        f"    def apply(self, points):\n{body}\n"
    ).encode()
    cls: type[Any] = load_in_worker(
        source,
        "noise-removal",
        "dbscan",
        version,
        memory_mb=limits.get("memory_mb", 256.0),
        call_s=limits.get("hang_s", 5.0),
        import_s=30.0,
    )
    return cls


def _guard(cls: type[Any]) -> tuple[Any, Dbscan, list[str], list[str]]:
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
    )()
    return kernel, fallback, failures, stuck


def _stuck_run(version: str, body: str, **limits: float) -> tuple[list[str], list[str]]:
    cls = _remote(version, body, **limits)
    worker = cls.worker
    try:
        kernel, fallback, failures, stuck = _guard(cls)
        points = _points()
        first = kernel.apply(points)
        second = kernel.apply(points)  # answered by the fallback: the stuck kernel is not called again
        want = fallback.apply(points)
        for got in (first, second):
            assert np.array_equal(got.points, want.points) and np.array_equal(got.keep, want.keep)
        assert worker.proc.poll() is not None  # killed, not left running
    finally:
        worker.close()
    return failures, stuck


def test_a_call_that_hangs_is_answered_by_the_fallback_and_its_worker_killed() -> None:
    failures, stuck = _stuck_run("9.0.4", "        while True:\n            pass", hang_s=0.5)
    assert failures == stuck == ["dbscan 9.0.4 did not return within 0.5 s (hung); its process was killed"]


def test_a_call_stuck_in_c_holding_the_gil_does_not_stop_the_caller() -> None:
    body = (
        "        import re\n        re.match(r'(a+)+$', 'a' * 40 + 'b')\n        return super().apply(points)"
    )
    failures, stuck = _stuck_run("9.0.7", body, hang_s=0.5)
    assert failures == stuck == ["dbscan 9.0.7 did not return within 0.5 s (hung); its process was killed"]


def test_a_call_that_allocates_past_its_limit_fails_in_its_worker() -> None:
    body = "        blocks = []\n        while True:\n            blocks.append(np.ones(1 << 20))"
    cls = _remote("9.0.8", body, memory_mb=64, hang_s=30)
    try:
        kernel, fallback, failures, stuck = _guard(cls)
        got = kernel.apply(_points())
        assert np.array_equal(got.points, fallback.apply(_points()).points)
        assert failures == ["dbscan 9.0.8 out of memory: the kernel needed more than its 64 MB limit"]
        assert stuck == []  # the worker survived its MemoryError; the agent rolls the kernel back
    finally:
        cls.worker.close()


def test_an_exception_in_the_worker_is_a_failure_not_stuck() -> None:
    cls = _remote("9.0.5", "        raise ZeroDivisionError('planted')")
    try:
        kernel, _, failures, stuck = _guard(cls)
        kernel.apply(_points())
        assert len(failures) == 1 and stuck == []
        assert failures[0].startswith("dbscan 9.0.5 raised ZeroDivisionError: planted (line ")
    finally:
        cls.worker.close()


def test_a_worker_that_dies_is_detected_and_never_called_again() -> None:
    cls = _remote("9.0.6", "        import os\n        os._exit(3)")
    try:
        kernel, fallback, failures, stuck = _guard(cls)
        for _ in range(2):
            got = kernel.apply(_points())
            assert np.array_equal(got.points, fallback.apply(_points()).points)
        assert failures == stuck and len(failures) == 1
        assert failures[0].startswith("dbscan 9.0.6: its process exited with code 3 during a call")
    finally:
        cls.worker.close()


def test_parameters_are_validated_by_the_kernel_in_its_worker() -> None:
    cls = _remote("9.0.9", "        return super().apply(points)")
    try:
        kernel: Any = cls({"epsilon_m": 0.07})
        assert kernel.params.epsilon_m == 0.07 and kernel.get_params()["min_points"] == 3
        got = kernel.apply(_points())
        assert np.array_equal(got.points, Dbscan(epsilon_m=0.07).apply(_points()).points)
        with pytest.raises(KernelParameterError, match="epsilon_m"):
            cls({"epsilon_m": -1.0})
    finally:
        cls.worker.close()
