"""The kernel conformance battery (docs/architecture.md, "How to add a kernel") as functions that return
problems.

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

Each stage's description (:data:`shared.kernels.stages.STAGES`) says how a point set is fed to its
kernels (:func:`stage_input` / :func:`run_stage`), what its results must satisfy (:func:`check_result`)
and what ``nan-inf`` and ``line-1000`` expect of it; the probe inputs are :mod:`shared.kernels.probes`.
Nothing here asserts or does I/O: :func:`check_kernel` returns a list of problems, each
``"<check>: <stage/name@version>: <what was wrong>"``, empty when the kernel conforms. A kernel that
raises is a problem, never an exception out of this module.

Cost: the battery applies the kernel about 12 times on at most 1000 points (twice on a ~600-point room
scan); for the built-ins that is tens of milliseconds once compiled.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable, Iterable, Mapping
from typing import Any

import numpy as np

from shared.errors import KernelParameterError
from shared.kernels.base import Kernel, Stage
from shared.kernels.probes import MOTION, moved_copy, points_to_scan, readonly, room_scan, wall_points
from shared.kernels.stages import spec_of
from shared.types import FloatArray

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


def stage_input(stage: Stage | str, points: FloatArray) -> tuple[Any, ...]:
    """The positional arguments of ``apply`` for ``stage`` built from one point set ``(N, 2)`` (metres):
    the stage description's ``probe`` (:data:`shared.kernels.stages.STAGES`). Segmentation: a scan of the
    points; straight-line: the points in one group; scan-matching: the points as reference and their
    :func:`~shared.kernels.probes.moved_copy` as current scan, from the identity; otherwise the points.
    """
    return spec_of(stage).probe(points)


def run_stage(kernel: Kernel[Any], points: FloatArray) -> Any:
    """Apply ``kernel`` to ``points`` in its stage's form (see :func:`stage_input`)."""
    apply: Callable[..., Any] = kernel.apply  # type: ignore[attr-defined]
    return apply(*stage_input(kernel.stage, points))


# -------------------------------------------------------------------------------------------- results
def check_result(stage: Stage | str, result: Any, n_in: int) -> list[str]:
    """Problems with a stage's result: type, shapes, finiteness and invariants (empty when it is valid),
    as the stage description's ``check`` (:mod:`shared.kernels.checks`) says.

    ``n_in`` is the number of input points (rows of the ``(N, 2)`` array, non-finite rows included). Never
    raises: a result too broken to inspect is reported as such. O(N + L).
    """
    spec = spec_of(stage)
    if not isinstance(result, spec.result):
        return [f"returned {type(result).__name__}: expected {spec.result.__name__}"]
    try:
        return spec.check(result, n_in)
    except Exception as exc:  # garbage inside a result of the right type (lists, None, wrong dtypes)
        return [f"result could not be checked: {type(exc).__name__}: {exc}"]


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
    out.extend(spec_of(kernel.stage).on_nonfinite(result, rows))
    return out


def _all_noise(kernel: Kernel[Any], cls: type[Kernel[Any]]) -> list[str]:
    rng = np.random.default_rng(3)
    pts = rng.uniform(-4.0, 4.0, size=(300, 2))
    pts[:, 0] = np.abs(pts[:, 0]) + 0.3  # in front of the scanner, for the segmentation adapter
    return _checked(kernel, pts)[1]


def _line_1000(kernel: Kernel[Any], cls: type[Kernel[Any]]) -> list[str]:
    pts = wall_points(1000)
    result, out = _checked(kernel, pts)
    if out:
        return out
    return spec_of(kernel.stage).on_wall(kernel, result, pts)


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
