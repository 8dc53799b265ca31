"""The kernel conformance battery (issue 2 §5, issue 5 item 4) as functions that return problems.

Every kernel, built-in or downloaded, must pass the same checks before it may run in the pipeline:

==================  ===================================================================================
check               what it feeds / asserts
==================  ===================================================================================
``empty``           no points at all
``one-point``       a single point
``duplicates``      three copies of one point
``nan-inf``         200 wall points with NaN/inf rows: those rows are dropped / labelled -1
``all-noise``       300 uniformly scattered points
``line-1000``       1000 points on one wall: lines, centroids, segments and matches land on the wall
``room-scan``       a simulated URG-04LX scan of the default world with 5 % clutter
``determinism``     same input and parameters give the same result; input not mutated; result read-only
``params``          parameters round-trip through a plain JSON dict; every parameter is documented
``bad-params``      out-of-range, mistyped and unknown parameters raise a clear ``KernelParameterError``
==================  ===================================================================================

Each stage has an adapter (:func:`stage_input` / :func:`run_stage`) that feeds a point set to the kernel in
the stage's ``apply`` form, and a checker (:func:`check_result`) that validates the result's types, shapes
and invariants. Nothing here asserts or does I/O: :func:`check_kernel` returns a list of problems, each
``"<check>: <stage/name@version>: <what was wrong>"``, empty when the kernel conforms. A kernel that raises
is a problem, never an exception out of this module.

Cost: the battery applies the kernel about 12 times on at most 1000 points (twice on a ~600-point room
scan); for the built-ins that is tens of milliseconds once compiled.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable, Iterable, Mapping
from functools import lru_cache
from typing import Any

import numpy as np

from shared.errors import KernelParameterError
from shared.kernels.base import Kernel, Stage
from shared.kernels.results import Clusters, Lines, Match, NoiseResult, Segments
from shared.types import URG04LX, FloatArray, Pose2D, Scan

__all__ = [
    "CHECKS",
    "MOTION",
    "check_kernel",
    "check_result",
    "moved_copy",
    "points_to_scan",
    "read_only_problems",
    "readonly",
    "results_equal",
    "room_scan",
    "run_stage",
    "stage_input",
    "wall_points",
]

#: Motion between the reference and the current scan fed to scan matchers.
MOTION = Pose2D(0.05, -0.03, 0.02)


# ---------------------------------------------------------------------------------------------- inputs
def points_to_scan(points: FloatArray) -> Scan:
    """A URG-04LX scan whose returns are ``points`` (snapped to the nearest beam; non-finite rows -> inf).

    O(N + beams).
    """
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


def moved_copy(points: FloatArray) -> FloatArray:
    """The "current scan" for scan matchers: ``points`` seen after the robot moved by ``MOTION^-1``. O(N)."""
    with np.errstate(invalid="ignore"):
        return MOTION.transform_points(np.asarray(points, dtype=np.float64))


def stage_input(stage: Stage | str, points: FloatArray) -> tuple[Any, ...]:
    """The positional arguments of ``apply`` for ``stage`` built from one point set ``(N, 2)`` (metres).

    segmentation: a scan of the points; straight-line: the points in one group; scan-matching: the points
    as reference and their :func:`moved_copy` as current scan, from the identity; otherwise the points.
    """
    stage = Stage(stage)
    if stage == Stage.SEGMENTATION:
        return (points_to_scan(points),)
    if stage == Stage.STRAIGHT_LINE:
        return (points, np.zeros(len(points), dtype=np.intp))
    if stage == Stage.SCAN_MATCHING:
        return (points, moved_copy(points), Pose2D())
    return (points,)


def run_stage(kernel: Kernel[Any], points: FloatArray) -> Any:
    """Apply ``kernel`` to ``points`` in its stage's form (see :func:`stage_input`)."""
    apply: Callable[..., Any] = kernel.apply  # type: ignore[attr-defined]
    return apply(*stage_input(kernel.stage, points))


def wall_points(n: int = 1000, seed: int = 0) -> FloatArray:
    """``n`` points along a wall 2 m in front of the scanner, y from -1.5 to 1.5 m, 2 mm noise (seeded)."""
    rng = np.random.default_rng(seed)
    y = np.linspace(-1.5, 1.5, n)
    return np.column_stack([2.0 + rng.normal(0, 0.002, n), y])


def readonly(arr: FloatArray) -> FloatArray:
    """A read-only float64 copy of ``arr`` (kernels must accept read-only input)."""
    out = np.array(arr, dtype=np.float64, copy=True)
    out.setflags(write=False)
    return out


@lru_cache(maxsize=1)
def room_scan() -> Scan:
    """A URG-04LX scan in the default world with 5 % clutter returns (seeded, cached; scans are immutable)."""
    from shared.sim import RangeNoise, default_world, simulate_scan

    rng = np.random.default_rng(1)
    return simulate_scan(default_world(), Pose2D(4.5, 2.0, np.pi), rng, RangeNoise(outlier_rate=0.05))


# -------------------------------------------------------------------------------------------- results
def check_result(stage: Stage | str, result: Any, n_in: int) -> list[str]:
    """Problems with a stage's result: type, shapes, finiteness and invariants (empty when it is valid).

    ``n_in`` is the number of input points (rows of the ``(N, 2)`` array, non-finite rows included). Never
    raises: a result too broken to inspect is reported as such. O(N + L).
    """
    stage = Stage(stage)
    try:
        return _check_result(stage, result, n_in)
    except Exception as exc:  # garbage inside a result of the right type (lists, None, wrong dtypes)
        return [f"result could not be checked: {type(exc).__name__}: {exc}"]


def _check_result(stage: Stage, result: Any, n_in: int) -> list[str]:
    out: list[str] = []
    expected: dict[Stage, type[Any]] = {
        Stage.SEGMENTATION: Segments,
        Stage.NOISE_REMOVAL: NoiseResult,
        Stage.CLUSTERING: Clusters,
        Stage.STRAIGHT_LINE: Lines,
        Stage.SCAN_MATCHING: Match,
    }
    if not isinstance(result, expected[stage]):
        return [f"returned {type(result).__name__}: expected {expected[stage].__name__}"]

    def need(ok: Any, what: str) -> None:
        if not bool(ok):
            out.append(what)

    if stage == Stage.SEGMENTATION:
        n = len(result.points)
        need(
            result.points.shape == (n, 2) and result.beam_index.shape == (n,) and result.labels.shape == (n,),
            f"Segments shapes points {result.points.shape}, beam_index {result.beam_index.shape}, labels "
            f"{result.labels.shape}: expected ({n}, 2), ({n},), ({n},)",
        )
        need(np.all(np.isfinite(result.points)), "Segments.points has non-finite values")
        lab = result.labels[result.labels >= 0]
        need(np.all(np.diff(lab) >= 0), "segment labels must increase along the scan")
        need(np.all(result.labels >= -1), "Segments.labels has values below -1")
    elif stage == Stage.NOISE_REMOVAL:
        need(
            result.keep.shape == (n_in,) and result.keep.dtype == np.bool_,
            f"NoiseResult.keep is {result.keep.dtype} {result.keep.shape}: expected bool ({n_in},)",
        )
        need(
            result.points.ndim == 2 and result.points.shape[1] == 2,
            f"NoiseResult.points has shape {result.points.shape}: expected (M, 2)",
        )
        need(
            result.points.shape[0] >= int(result.keep.sum()),
            f"NoiseResult.points has {result.points.shape[0]} rows:"
            f" fewer than the {int(result.keep.sum())} kept",
        )
        need(
            result.labels.shape == (result.points.shape[0],),
            f"NoiseResult.labels has shape {result.labels.shape}: expected ({result.points.shape[0]},)",
        )
        need(np.all(np.isfinite(result.points)), "NoiseResult.points has non-finite values")
        need(np.all(result.labels >= 0), "NoiseResult.labels has negative values")
    elif stage == Stage.CLUSTERING:
        k = result.n_clusters
        need(
            result.centroids.shape == (k, 2) and np.all(np.isfinite(result.centroids)),
            f"Clusters.centroids has shape {result.centroids.shape} or non-finite values:"
            f" expected finite ({k}, 2)",
        )
        need(
            result.labels.shape == (n_in,),
            f"Clusters.labels has shape {result.labels.shape}: expected ({n_in},)",
        )
        need(
            np.all((result.labels >= -1) & (result.labels < max(k, 1))),
            f"Clusters.labels outside -1..{max(k, 1) - 1}",
        )
        need(
            math.isfinite(result.objective) and result.objective >= 0.0,
            f"Clusters.objective is {result.objective!r}: expected finite and >= 0",
        )
        if result.memberships is not None:
            need(
                result.memberships.shape == (n_in, k),
                f"Clusters.memberships has shape {result.memberships.shape}: expected ({n_in}, {k})",
            )
    elif stage == Stage.STRAIGHT_LINE:
        n = result.n_lines
        need(
            result.segments.shape == (n, 4) and np.all(np.isfinite(result.segments)),
            f"Lines.segments has shape {result.segments.shape} or non-finite values:"
            f" expected finite ({n}, 4)",
        )
        need(
            result.rho_m.shape
            == result.theta_rad.shape
            == result.group.shape
            == result.support.shape
            == (n,),
            f"Lines.rho_m/theta_rad/group/support shapes {result.rho_m.shape}/{result.theta_rad.shape}/"
            f"{result.group.shape}/{result.support.shape}: expected ({n},) each",
        )
        need(
            np.all((result.theta_rad >= 0.0) & (result.theta_rad < math.pi)),
            "Lines.theta_rad outside [0, pi)",
        )
        if not out:  # end points lie on the reported line
            for i, ((x0, y0, x1, y1), rho, th) in enumerate(
                zip(result.segments, result.rho_m, result.theta_rad, strict=True)
            ):
                for x, y in ((x0, y0), (x1, y1)):
                    off = abs(x * math.cos(th) + y * math.sin(th) - rho)
                    if not off < 1e-6:
                        out.append(f"line {i}: end point ({x}, {y}) is {off} m off its line (rho, theta)")
    else:
        need(isinstance(result.pose, Pose2D), f"Match.pose is {type(result.pose).__name__}: expected Pose2D")
        need(
            0.0 <= result.inlier_ratio <= 1.0 and result.n_iter >= 0,
            f"Match.inlier_ratio {result.inlier_ratio!r} outside [0, 1] or n_iter {result.n_iter!r} < 0",
        )
        need(result.rmse_m >= 0.0, f"Match.rmse_m is {result.rmse_m!r}: expected >= 0")
    return out


def results_equal(a: Any, b: Any) -> bool:
    """Field-by-field equality of two results (arrays compared exactly, NaN == NaN). O(size)."""
    if type(a) is not type(b):
        return False
    for name in getattr(a, "__slots__", ()):
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


def read_only_problems(result: Any) -> list[str]:
    """One problem per writeable array field of ``result``."""
    out: list[str] = []
    for name in getattr(result, "__slots__", ()):
        value = getattr(result, name)
        if isinstance(value, np.ndarray) and value.flags.writeable:
            out.append(f"{type(result).__name__}.{name} must be read-only")
    return out


# ------------------------------------------------------------------------------------------- the checks
def _ident(cls: type[Any]) -> str:
    return f"{getattr(cls, 'stage', '?')}/{getattr(cls, 'name', cls.__name__)}@{getattr(cls, 'version', '?')}"


def _raised(exc: BaseException) -> str:
    return f"raised {type(exc).__name__}: {exc}"


def _checked(kernel: Kernel[Any], points: FloatArray) -> tuple[Any, list[str]]:
    """Run on a read-only copy of ``points`` and check the result; ``(result or None, problems)``."""
    try:
        result = run_stage(kernel, readonly(points))
    except Exception as exc:
        return None, [_raised(exc)]
    return result, check_result(kernel.stage, result, len(points))


def _degenerate(points: FloatArray) -> Callable[[Kernel[Any], type[Kernel[Any]]], list[str]]:
    def check(kernel: Kernel[Any], cls: type[Kernel[Any]]) -> list[str]:
        return _checked(kernel, points)[1]

    return check


def _nan_inf(kernel: Kernel[Any], cls: type[Kernel[Any]]) -> list[str]:
    bad = wall_points(200).copy()
    rows = [3, 50, 120]
    bad[rows] = [[np.nan, 1.0], [np.inf, -np.inf], [np.nan, np.nan]]
    result, out = _checked(kernel, bad)
    if out:
        return out
    if kernel.stage == Stage.NOISE_REMOVAL and result.keep[rows].any():
        out.append(f"kept non-finite rows {[r for r in rows if result.keep[r]]}")
    if kernel.stage == Stage.CLUSTERING and not np.all(result.labels[rows] == -1):
        out.append(f"non-finite rows {rows} labelled {result.labels[rows].tolist()}: expected -1")
    return out


def _all_noise(kernel: Kernel[Any], cls: type[Kernel[Any]]) -> list[str]:
    rng = np.random.default_rng(3)
    pts = rng.uniform(-4.0, 4.0, size=(300, 2))
    pts[:, 0] = np.abs(pts[:, 0]) + 0.3  # in front of the scanner, for the segmentation adapter
    return _checked(kernel, pts)[1]


def _close(actual: Any, target: float, atol: float) -> bool:
    """``np.testing.assert_allclose(actual, target, atol=atol)`` as a predicate (NaN is never close)."""
    return bool(np.allclose(np.asarray(actual, dtype=np.float64), target, rtol=1e-7, atol=atol))


def _line_1000(kernel: Kernel[Any], cls: type[Kernel[Any]]) -> list[str]:
    pts = wall_points(1000)
    result, out = _checked(kernel, pts)
    if out:
        return out
    stage = kernel.stage
    if stage == Stage.STRAIGHT_LINE:
        if result.n_lines < 1:
            return ["found no line in 1000 points on one wall"]
        # every end point is on the wall x = 2 (centroid-join joins the noisy points themselves)
        if not _close(result.segments[:, [0, 2]], 2.0, 0.03):
            out.append("line end points are not on the wall x = 2 m (tolerance 0.03 m)")
        if kernel.name != "centroid-join":
            # a fitted line is the wall: normal along x, i.e. theta ~ 0 (rho ~ 2) or theta ~ pi (rho ~ -2)
            near_pi = result.theta_rad > math.pi / 2
            off_axis = np.where(near_pi, math.pi - result.theta_rad, result.theta_rad)
            if not np.all(off_axis < math.radians(2.0)):
                out.append("fitted line direction is more than 2 deg off the wall's")
            if not _close(np.where(near_pi, -result.rho_m, result.rho_m), 2.0, 0.03):
                out.append("fitted line distance rho is not the wall's 2 m (tolerance 0.03 m)")
    if stage == Stage.CLUSTERING and not np.all(np.abs(result.centroids[:, 0] - 2.0) < 0.01):
        out.append("centroids are not on the wall x = 2 m (tolerance 0.01 m)")
    if stage == Stage.SEGMENTATION and result.n_segments < 1:
        out.append("found no segment in 1000 points on one wall")
    if stage == Stage.SCAN_MATCHING:
        # along a single wall only the wall's normal offset and direction are observable:
        # the matched current scan must land back on the wall x = 2
        aligned = result.pose.transform_points(moved_copy(pts))
        if not _close(aligned[:, 0], 2.0, 0.01):
            out.append("the matched current scan does not land back on the wall x = 2 m (tolerance 0.01 m)")
    return out


def _room_scan(kernel: Kernel[Any], cls: type[Kernel[Any]]) -> list[str]:
    pts, _ = room_scan().to_points()
    return _checked(kernel, pts)[1]


def _determinism(kernel: Kernel[Any], cls: type[Kernel[Any]]) -> list[str]:
    pts, _ = room_scan().to_points()
    pts = np.array(pts, dtype=np.float64, copy=True)  # writeable: a kernel must not change it anyway
    original = pts.copy()
    try:
        first = run_stage(kernel, pts)
        second = run_stage(cls(kernel.get_params()), pts)
    except Exception as exc:
        return [_raised(exc)]
    out: list[str] = []
    if not np.array_equal(pts, original):
        out.append("apply must not modify its input")
    if not results_equal(first, second):
        out.append("same input and parameters must give the same result")
    return out + read_only_problems(first)


def _params(kernel: Kernel[Any], cls: type[Kernel[Any]]) -> list[str]:
    out: list[str] = []
    try:
        params = kernel.get_params()
        rebuilt = cls(json.loads(json.dumps(params)))
    except Exception as exc:
        return [f"parameters do not round-trip through JSON: {_raised(exc)}"]
    if rebuilt != kernel:
        out.append("a kernel rebuilt from its JSON parameters is not equal to the original")
    if rebuilt.get_params() != params:
        out.append(f"parameters changed in the round trip: {params!r} -> {rebuilt.get_params()!r}")
    try:
        schema = kernel.param_schema()
        json.dumps(schema)
    except Exception as exc:
        return [*out, f"parameter schema is not JSON: {_raised(exc)}"]
    props = schema.get("properties", {})
    if set(props) != set(params):
        out.append(f"schema properties {sorted(props)} differ from the parameters {sorted(params)}")
    for name, prop in props.items():
        if not prop.get("description"):
            out.append(f"parameter {name} needs a description")
    return out


def _violations(prop: dict[str, Any]) -> list[Any]:
    """Values that break one JSON-Schema property's bounds, type or choices."""
    found: list[Any] = []
    kind = prop.get("type")
    if "minimum" in prop:
        found.append(prop["minimum"] - 1)
    if "exclusiveMinimum" in prop:
        found.append(prop["exclusiveMinimum"])
    if "maximum" in prop:
        found.append(prop["maximum"] + 1)
    if "exclusiveMaximum" in prop:
        found.append(prop["exclusiveMaximum"])
    if kind in ("number", "integer"):
        found.append("not-a-number")
    if "enum" in prop:
        found.append("not-one-of-the-choices")
    return found


def _bad_params(kernel: Kernel[Any], cls: type[Kernel[Any]]) -> list[str]:
    out: list[str] = []
    tried = 0
    for name, prop in kernel.param_schema().get("properties", {}).items():
        for bad in _violations(prop):
            tried += 1
            try:
                cls({name: bad})
            except KernelParameterError as exc:
                message = str(exc)
                if not (kernel.name in message and name in message and repr(bad) in message):
                    out.append(f"{name}={bad!r}: the message does not name the kernel, parameter and value")
                if not isinstance(bad, str) and "allowed range" not in message:
                    out.append(f"{name}={bad!r}: the message does not give the allowed range")
            except Exception as exc:
                out.append(f"{name}={bad!r} {_raised(exc)}: expected KernelParameterError")
            else:
                out.append(f"{name}={bad!r} was accepted: expected KernelParameterError")
    if tried == 0:
        out.append("every kernel has at least one bounded numeric parameter")
    try:
        cls({"no_such_parameter": 1})
    except KernelParameterError as exc:
        if not re.search("unknown parameter", str(exc)):
            out.append("an unknown parameter's error does not say 'unknown parameter'")
    except Exception as exc:
        out.append(f"an unknown parameter {_raised(exc)}: expected KernelParameterError")
    else:
        out.append("an unknown parameter was accepted: expected KernelParameterError")
    return out


_Check = Callable[[Kernel[Any], type[Kernel[Any]]], list[str]]

_BATTERY: dict[str, _Check] = {
    "empty": _degenerate(np.zeros((0, 2))),
    "one-point": _degenerate(np.array([[1.0, 0.5]])),
    "duplicates": _degenerate(np.array([[1.0, 0.5], [1.0, 0.5], [1.0, 0.5]])),
    "nan-inf": _nan_inf,
    "all-noise": _all_noise,
    "line-1000": _line_1000,
    "room-scan": _room_scan,
    "determinism": _determinism,
    "params": _params,
    "bad-params": _bad_params,
}

#: Names of the checks :func:`check_kernel` runs, in order.
CHECKS: tuple[str, ...] = tuple(_BATTERY)


def check_kernel(
    cls: type[Kernel[Any]], params: Mapping[str, Any] | None = None, *, only: Iterable[str] | None = None
) -> list[str]:
    """Run the conformance battery on kernel class ``cls`` built with ``params`` (default: its defaults).

    Returns the problems, each ``"<check>: <stage/name@version>: <what was wrong>"``; empty means the kernel
    conforms. ``only`` restricts the run to some of :data:`CHECKS` (unknown names raise ``ValueError``).
    Pure apart from running the kernel; never raises because of the kernel. About 12 ``apply`` calls on at
    most 1000 points.
    """
    names = CHECKS if only is None else tuple(only)
    unknown = [n for n in names if n not in _BATTERY]
    if unknown:
        raise ValueError(f"unknown conformance checks {unknown}: expected some of {', '.join(CHECKS)}")
    ident = _ident(cls)
    if not (isinstance(cls, type) and issubclass(cls, Kernel)):
        return [f"declaration: {ident}: {cls!r} is not a Kernel subclass"]
    try:
        kernel = cls(params)
    except Exception as exc:
        return [f"construct: {ident}: {_raised(exc)}"]
    problems: list[str] = []
    for name in names:
        try:
            found = _BATTERY[name](kernel, cls)
        except Exception as exc:  # a result with the right type but unusable fields
            found = [_raised(exc)]
        problems.extend(f"{name}: {ident}: {p}" for p in found)
    return problems
