"""Run-time guard of hot-swapped kernels against garbage (issue 9 item 4): a kernel that passed every
check before it ran and then returns a bad result in service (non-finite values, wrong shapes, wrong type)
is answered by the kernel it replaced, and the agent is told, so the garbage never reaches the map. The
same through a real agent and server: test_rel_supply_live.py::test_supply_chain_matrix[nan-in-service].
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from robot_agent.guard import guarded
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
