"""The conformance test every registered kernel passes.

The battery lives in :mod:`shared.kernels.conformance` (the robot agent runs it on downloaded kernels):
empty input, one point, duplicates, NaN/inf rows, all-noise input, a thousand points on one line, a room
scan, determinism with the input untouched and read-only results, parameters round-tripping through a plain
dict, and bad parameters rejected clearly. Here every registered kernel must pass every check, one test per
(kernel, check); and the battery itself must catch kernels that break each rule.
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil
from typing import Any

import numpy as np
import pytest

import shared.kernels
from shared.kernels import REGISTRY, Kernel, KernelInfo, NoiseRemovalKernel, NoiseResult, Stage, conformance
from shared.kernels.conformance import (
    CHECKS,
    check_kernel,
    check_result,
    points_to_scan,
    run_stage,
    stage_input,
)
from shared.kernels.noise import Dbscan
from shared.types import Scan

KERNELS = REGISTRY.list()  # as collected: what test_conformance runs on
# Written out so that a built-in kernel that disappears fails here by name; checked exactly against the
# registry, and the registry exactly against the kernel classes under shared/kernels/.
EXPECTED_BUILTINS = {
    ("segmentation", "abd-iepf"),
    ("noise-removal", "dbscan"),
    ("noise-removal", "erosion"),
    ("noise-removal", "dilation"),
    ("noise-removal", "opening"),
    ("clustering", "kmeans"),
    ("clustering", "fcm"),
    ("straight-line", "centroid-join"),
    ("straight-line", "svd"),
    ("straight-line", "hough"),
    ("straight-line", "hough-cluster"),
    ("scan-matching", "icp"),
    ("scan-matching", "icp-line"),
}


def _ids(info: KernelInfo) -> str:
    return f"{info.stage}/{info.name}"


def _kernel_classes_of_shared_kernels() -> set[type[Kernel[Any]]]:
    """Every concrete, named kernel class defined in a module under shared/kernels/, each module imported."""

    def fail(name: str) -> None:
        raise ImportError(f"cannot import {name}")

    found: set[type[Kernel[Any]]] = set()
    for mod in pkgutil.walk_packages(shared.kernels.__path__, "shared.kernels.", onerror=fail):
        module = importlib.import_module(mod.name)
        for obj in vars(module).values():
            if (
                isinstance(obj, type)
                and issubclass(obj, Kernel)
                and obj.__module__ == module.__name__
                and getattr(obj, "name", None)
                and not inspect.isabstract(obj)
            ):
                found.add(obj)
    return found


def _builtins(infos: list[KernelInfo]) -> set[type[Kernel[Any]]]:
    return {i.cls for i in infos if i.cls.__module__.startswith("shared.kernels.")}


def _keys(classes: set[type[Kernel[Any]]]) -> set[tuple[str, str]]:
    return {(str(c.stage), c.name) for c in classes}


def test_every_builtin_is_registered() -> None:
    """The registry's built-ins are exactly the expected ones: a new one must be added to the list above,
    a removed one fails here by name."""
    got = _keys(_builtins(REGISTRY.list()))
    assert got == EXPECTED_BUILTINS, (
        f"registered, not expected: {sorted(got - EXPECTED_BUILTINS)}; "
        f"expected, not registered: {sorted(EXPECTED_BUILTINS - got)}"
    )


def test_every_kernel_class_under_shared_kernels_is_registered_and_conformance_tested() -> None:
    """A kernel class defined under shared/kernels/ but not registered (a forgotten ``@register``, or a
    module its package does not import) fails here, and so does a registered built-in that no module defines;
    each of them is one of the kernels test_conformance was collected for."""
    found = _kernel_classes_of_shared_kernels()
    assert found, "no kernel class found under shared/kernels/"
    registered = _keys(_builtins(REGISTRY.list()))
    assert registered == _keys(found), (
        f"defined, not registered: {sorted(_keys(found) - registered)}; "
        f"registered, not defined under shared/kernels/: {sorted(registered - _keys(found))}"
    )
    assert _builtins(REGISTRY.list()) == found
    missing = _keys(found - _builtins(KERNELS))
    assert not missing, f"not registered when test_conformance was collected (not imported?): {missing}"


@pytest.mark.parametrize("check", CHECKS)
@pytest.mark.parametrize("info", KERNELS, ids=_ids)
def test_conformance(info: KernelInfo, check: str) -> None:
    assert check_kernel(info.cls, only=[check]) == []


def test_room_scan_matches_the_fixture(room_scan: Scan) -> None:
    assert np.array_equal(conformance.room_scan().ranges_m, room_scan.ranges_m, equal_nan=True)


def test_stage_input_forms() -> None:
    pts = np.array([[1.0, 0.5], [1.0, -0.5]])
    (scan,) = stage_input(Stage.SEGMENTATION, pts)
    assert isinstance(scan, Scan) and np.isfinite(scan.ranges_m).sum() == 2
    line_args = stage_input("straight-line", pts)
    assert len(line_args) == 2 and np.array_equal(line_args[1], [0, 0])
    assert len(stage_input(Stage.SCAN_MATCHING, pts)) == 3
    assert stage_input(Stage.CLUSTERING, pts)[0] is pts
    assert isinstance(run_stage(Dbscan(), pts), NoiseResult)
    assert isinstance(points_to_scan(np.zeros((0, 2))), Scan)


def test_checks_list_and_unknown_check() -> None:
    assert CHECKS[0] == "empty" and "bad-params" in CHECKS and len(CHECKS) == len(set(CHECKS))
    with pytest.raises(ValueError, match="unknown conformance checks"):
        check_kernel(Dbscan, only=["no-such-check"])


def test_check_kernel_with_params_and_bad_params() -> None:
    assert check_kernel(Dbscan, {"epsilon_m": 0.1}, only=["room-scan", "params"]) == []
    problems = check_kernel(Dbscan, {"epsilon_m": -1.0})
    assert len(problems) == 1 and problems[0].startswith("construct: noise-removal/dbscan@1.0.0: raised")


# ------------------------------------------------------------------ the battery catches broken kernels
class _Broken(NoiseRemovalKernel[Any]):
    """Base of deliberately broken noise-removal kernels (never registered)."""

    name = "broken"
    Params = Dbscan.Params

    def _good(self, points: Any) -> NoiseResult:
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        keep = np.all(np.isfinite(pts), axis=1)
        kept = pts[keep].copy()
        labels = np.zeros(len(kept), dtype=np.intp)
        for arr in (keep, kept, labels):
            arr.setflags(write=False)
        return NoiseResult(keep, kept, labels)


class _Raises(_Broken):
    def apply(self, points: Any) -> NoiseResult:
        raise RuntimeError("boom")


class _Garbage(_Broken):
    def apply(self, points: Any) -> NoiseResult:
        return "garbage"  # type: ignore[return-value]


class _WrongShapes(_Broken):
    def apply(self, points: Any) -> NoiseResult:
        good = self._good(points)
        return NoiseResult(good.keep[:-1] if len(good.keep) else np.ones(3, bool), good.points, good.labels)


class _KeepsNaN(_Broken):
    def apply(self, points: Any) -> NoiseResult:
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        return NoiseResult(np.ones(len(pts), bool), pts.copy(), np.zeros(len(pts), dtype=np.intp))


class _Mutates(_Broken):
    def apply(self, points: Any) -> NoiseResult:
        if isinstance(points, np.ndarray) and points.flags.writeable and len(points):
            points[0, 0] += 1.0
        return self._good(points)


class _Random(_Broken):
    def apply(self, points: Any) -> NoiseResult:
        good = self._good(points)
        pts = np.array(good.points) + np.random.default_rng().normal(0, 1e-3, good.points.shape)
        pts.setflags(write=False)
        return NoiseResult(good.keep, pts, good.labels)


class _Writeable(_Broken):
    def apply(self, points: Any) -> NoiseResult:
        good = self._good(points)
        return NoiseResult(np.array(good.keep), np.array(good.points), np.array(good.labels))


@pytest.mark.parametrize(
    ("cls", "check", "expected"),
    [
        (_Raises, "empty", "empty: noise-removal/broken@1.0.0: raised RuntimeError: boom"),
        (_Garbage, "room-scan", "room-scan: noise-removal/broken@1.0.0: returned str: expected NoiseResult"),
        (_WrongShapes, "one-point", "NoiseResult.keep is bool"),
        (_KeepsNaN, "nan-inf", "NoiseResult.points has non-finite values"),
        (_Mutates, "determinism", "apply must not modify its input"),
        (_Random, "determinism", "same input and parameters must give the same result"),
        (_Writeable, "determinism", "NoiseResult.points must be read-only"),
    ],
)
def test_battery_reports_broken_kernels(cls: Any, check: str, expected: str) -> None:
    problems = check_kernel(cls, only=[check])
    assert any(expected in p for p in problems), problems
    assert all(p.startswith(f"{check}: noise-removal/broken@1.0.0: ") for p in problems)


def test_check_result_never_raises() -> None:
    bad = NoiseResult(None, None, None)  # type: ignore[arg-type]
    (problem,) = check_result(Stage.NOISE_REMOVAL, bad, 3)
    assert problem.startswith("result could not be checked: AttributeError")


def test_room_scan_is_cached() -> None:
    assert conformance.room_scan() is conformance.room_scan()
