"""The conformance test every registered kernel passes (issue 2 §5).

Each stage has an adapter that feeds a point set to the kernel in the stage's ``apply`` form, and a
checker that validates the result's shapes and invariants. Every kernel then runs the same checks: empty
input, one point, NaN/inf, all-noise input, a thousand points on one line, determinism, input not mutated,
read-only results, parameters round-tripping through a plain dict, and bad parameters rejected clearly.
"""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
import pytest

from shared.errors import KernelParameterError
from shared.kernels import (
    REGISTRY,
    Clusters,
    Kernel,
    KernelInfo,
    Lines,
    Match,
    NoiseResult,
    Segments,
    Stage,
)
from shared.types import URG04LX, FloatArray, Pose2D, Scan

KERNELS = REGISTRY.list()
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
}


def _ids(info: KernelInfo) -> str:
    return f"{info.stage}/{info.name}"


def points_to_scan(points: FloatArray) -> Scan:
    """A URG-04LX scan whose returns are ``points`` (snapped to the nearest beam; non-finite rows -> NaN)."""
    ranges = np.full(URG04LX.beam_count, np.nan)
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    finite = np.all(np.isfinite(pts), axis=1)
    r = np.hypot(pts[finite, 0], pts[finite, 1])
    beam = np.rint(
        (np.arctan2(pts[finite, 1], pts[finite, 0]) - URG04LX.angle_min_rad) / URG04LX.angle_increment_rad
    ).astype(int)
    ok = (beam >= 0) & (beam < URG04LX.beam_count)
    ranges[beam[ok]] = r[ok]
    if (~finite).any():
        ranges[: int((~finite).sum())] = np.inf
    return Scan.from_geometry(URG04LX, ranges)


MOTION = Pose2D(0.05, -0.03, 0.02)


def moved_copy(points: FloatArray) -> FloatArray:
    """The "current scan" for scan matchers: ``points`` seen after the robot moved by ``MOTION^-1``."""
    with np.errstate(invalid="ignore"):
        return MOTION.transform_points(points)


def run(kernel: Kernel[Any], points: FloatArray) -> Any:
    """Apply ``kernel`` to ``points`` in its stage's form."""
    stage = kernel.stage
    if stage == Stage.SEGMENTATION:
        return kernel.apply(points_to_scan(points))  # type: ignore[attr-defined]
    if stage == Stage.STRAIGHT_LINE:
        return kernel.apply(points, np.zeros(len(points), dtype=np.intp))  # type: ignore[attr-defined]
    if stage == Stage.SCAN_MATCHING:
        return kernel.apply(points, moved_copy(points), Pose2D())  # type: ignore[attr-defined]
    return kernel.apply(points)  # type: ignore[attr-defined]


def check_result(stage: Stage, result: Any, n_in: int) -> None:
    """Shapes, finiteness and invariants of a stage's result."""
    if stage == Stage.SEGMENTATION:
        assert isinstance(result, Segments)
        n = len(result.points)
        assert (
            result.points.shape == (n, 2) and result.beam_index.shape == (n,) and result.labels.shape == (n,)
        )
        assert np.all(np.isfinite(result.points))
        lab = result.labels[result.labels >= 0]
        assert np.all(np.diff(lab) >= 0), "segment labels must increase along the scan"
        assert np.all(result.labels >= -1)
    elif stage == Stage.NOISE_REMOVAL:
        assert isinstance(result, NoiseResult)
        assert result.keep.shape == (n_in,) and result.keep.dtype == np.bool_
        assert result.points.ndim == 2 and result.points.shape[1] == 2
        assert result.points.shape[0] >= int(result.keep.sum())
        assert result.labels.shape == (result.points.shape[0],)
        assert np.all(np.isfinite(result.points)) and np.all(result.labels >= 0)
    elif stage == Stage.CLUSTERING:
        assert isinstance(result, Clusters)
        k = result.n_clusters
        assert result.centroids.shape == (k, 2) and np.all(np.isfinite(result.centroids))
        assert result.labels.shape == (n_in,)
        assert np.all((result.labels >= -1) & (result.labels < max(k, 1)))
        assert math.isfinite(result.objective) and result.objective >= 0.0
        if result.memberships is not None:
            assert result.memberships.shape == (n_in, k)
    elif stage == Stage.STRAIGHT_LINE:
        assert isinstance(result, Lines)
        n = result.n_lines
        assert result.segments.shape == (n, 4) and np.all(np.isfinite(result.segments))
        assert (
            result.rho_m.shape == result.theta_rad.shape == result.group.shape == result.support.shape == (n,)
        )
        assert np.all((result.theta_rad >= 0.0) & (result.theta_rad < math.pi))
        # end points lie on the reported line
        for (x0, y0, x1, y1), rho, th in zip(result.segments, result.rho_m, result.theta_rad, strict=True):
            for x, y in ((x0, y0), (x1, y1)):
                assert abs(x * math.cos(th) + y * math.sin(th) - rho) < 1e-6
    else:
        assert isinstance(result, Match)
        assert isinstance(result.pose, Pose2D)
        assert 0.0 <= result.inlier_ratio <= 1.0 and result.n_iter >= 0
        assert result.rmse_m >= 0.0


def results_equal(a: Any, b: Any) -> bool:
    """Field-by-field equality of two results (arrays compared exactly, NaN == NaN)."""
    if type(a) is not type(b):
        return False
    for name in a.__slots__:
        x, y = getattr(a, name), getattr(b, name)
        if isinstance(x, np.ndarray):
            if not np.array_equal(x, y, equal_nan=True):
                return False
        elif isinstance(x, float) and math.isnan(x):
            if not (isinstance(y, float) and math.isnan(y)):
                return False
        elif x != y:
            return False
    return True


def assert_read_only(result: Any) -> None:
    for name in result.__slots__:
        value = getattr(result, name)
        if isinstance(value, np.ndarray):
            assert not value.flags.writeable, f"{type(result).__name__}.{name} must be read-only"


def wall_points(n: int = 1000, seed: int = 0) -> FloatArray:
    """Points along a wall 2 m in front of the scanner, from y = -1.5 to 1.5 m."""
    rng = np.random.default_rng(seed)
    y = np.linspace(-1.5, 1.5, n)
    return np.column_stack([2.0 + rng.normal(0, 0.002, n), y])


def readonly(arr: FloatArray) -> FloatArray:
    out = np.array(arr, dtype=np.float64, copy=True)
    out.setflags(write=False)
    return out


def test_every_builtin_is_registered() -> None:
    got = {(str(i.stage), i.name) for i in KERNELS}
    assert got >= EXPECTED_BUILTINS


@pytest.fixture(params=KERNELS, ids=_ids)
def kernel(request: pytest.FixtureRequest) -> Kernel[Any]:
    info: KernelInfo = request.param
    return info.cls()


@pytest.mark.parametrize(
    "points",
    [
        pytest.param(np.zeros((0, 2)), id="empty"),
        pytest.param(np.array([[1.0, 0.5]]), id="one-point"),
        pytest.param(np.array([[1.0, 0.5], [1.0, 0.5], [1.0, 0.5]]), id="duplicates"),
    ],
)
def test_degenerate_inputs(kernel: Kernel[Any], points: FloatArray) -> None:
    result = run(kernel, readonly(points))
    check_result(kernel.stage, result, len(points))


def test_nan_and_inf_rows_are_ignored(kernel: Kernel[Any]) -> None:
    pts = wall_points(200)
    bad = pts.copy()
    bad[[3, 50, 120]] = [[np.nan, 1.0], [np.inf, -np.inf], [np.nan, np.nan]]
    result = run(kernel, readonly(bad))
    check_result(kernel.stage, result, len(bad))
    if kernel.stage == Stage.NOISE_REMOVAL:
        assert not result.keep[[3, 50, 120]].any()
    if kernel.stage == Stage.CLUSTERING:
        assert np.all(result.labels[[3, 50, 120]] == -1)


def test_all_noise_input(kernel: Kernel[Any]) -> None:
    rng = np.random.default_rng(3)
    pts = rng.uniform(-4.0, 4.0, size=(300, 2))
    pts[:, 0] = np.abs(pts[:, 0]) + 0.3  # in front of the scanner, for the segmentation adapter
    result = run(kernel, readonly(pts))
    check_result(kernel.stage, result, len(pts))


def test_thousand_points_on_one_line(kernel: Kernel[Any]) -> None:
    pts = wall_points(1000)
    result = run(kernel, readonly(pts))
    check_result(kernel.stage, result, len(pts))
    if kernel.stage == Stage.STRAIGHT_LINE:
        assert result.n_lines >= 1
        # every end point is on the wall x = 2 (centroid-join joins the noisy points themselves)
        np.testing.assert_allclose(result.segments[:, [0, 2]], 2.0, atol=0.03)
        if kernel.name != "centroid-join":
            # a fitted line is the wall: normal along x, i.e. theta ~ 0 (rho ~ 2) or theta ~ pi (rho ~ -2)
            near_pi = result.theta_rad > math.pi / 2
            off_axis = np.where(near_pi, math.pi - result.theta_rad, result.theta_rad)
            assert np.all(off_axis < math.radians(2.0))
            np.testing.assert_allclose(np.where(near_pi, -result.rho_m, result.rho_m), 2.0, atol=0.03)
    if kernel.stage == Stage.CLUSTERING:
        assert np.all(np.abs(result.centroids[:, 0] - 2.0) < 0.01)
    if kernel.stage == Stage.SEGMENTATION:
        assert result.n_segments >= 1
    if kernel.stage == Stage.SCAN_MATCHING:
        # along a single wall only the wall's normal offset and direction are observable:
        # the matched current scan must land back on the wall x = 2
        aligned = result.pose.transform_points(moved_copy(pts))
        np.testing.assert_allclose(aligned[:, 0], 2.0, atol=0.01)


def test_room_scan(kernel: Kernel[Any], room_scan: Scan) -> None:
    pts, _ = room_scan.to_points()
    result = run(kernel, readonly(pts))
    check_result(kernel.stage, result, len(pts))


def test_deterministic_and_input_untouched(kernel: Kernel[Any], room_scan: Scan) -> None:
    pts, _ = room_scan.to_points()
    original = pts.copy()
    first = run(kernel, pts)
    second = run(type(kernel)(kernel.get_params()), pts)
    assert np.array_equal(pts, original), "apply must not modify its input"
    assert results_equal(first, second), "same input and parameters must give the same result"
    assert_read_only(first)


def test_params_round_trip(kernel: Kernel[Any]) -> None:
    params = kernel.get_params()
    text = json.dumps(params)
    rebuilt = type(kernel)(json.loads(text))
    assert rebuilt == kernel
    assert rebuilt.get_params() == params
    schema = kernel.param_schema()
    json.dumps(schema)
    assert set(schema["properties"]) == set(params)
    for name, prop in schema["properties"].items():
        assert prop.get("description"), f"parameter {name} needs a description"


def _violations(prop: dict[str, Any]) -> list[Any]:
    out: list[Any] = []
    kind = prop.get("type")
    if "minimum" in prop:
        out.append(prop["minimum"] - 1)
    if "exclusiveMinimum" in prop:
        out.append(prop["exclusiveMinimum"])
    if "maximum" in prop:
        out.append(prop["maximum"] + 1)
    if "exclusiveMaximum" in prop:
        out.append(prop["exclusiveMaximum"])
    if kind in ("number", "integer"):
        out.append("not-a-number")
    if "enum" in prop:
        out.append("not-one-of-the-choices")
    return out


def test_out_of_range_parameters_are_rejected_clearly(kernel: Kernel[Any]) -> None:
    schema = kernel.param_schema()
    tried = 0
    for name, prop in schema["properties"].items():
        for bad in _violations(prop):
            with pytest.raises(KernelParameterError) as exc:
                type(kernel)({name: bad})
            message = str(exc.value)
            assert kernel.name in message and name in message and repr(bad) in message
            if not isinstance(bad, str):
                assert "allowed range" in message
            tried += 1
    assert tried > 0, "every kernel has at least one bounded numeric parameter"
    with pytest.raises(KernelParameterError, match="unknown parameter"):
        type(kernel)({"no_such_parameter": 1})
