"""The kernel contract (docs/design.md §4): one swappable, validated, pure implementation of one pipeline
stage.

Like a scikit-learn estimator, a kernel separates its *settings* (a frozen :class:`KernelParams` model,
validated on construction) from its *results* (returned by :meth:`apply`, never stored on the kernel).
``apply`` is pure: arrays in, a frozen result out, inputs untouched; the same input and parameters give the
same result (randomness comes from a ``seed`` parameter).

Each stage has an abstract base fixing ``apply``'s signature:

========================  ==============================================================  ==============
stage                     ``apply``                                                       returns
========================  ==============================================================  ==============
``segmentation``          ``apply(scan: Scan)``                                           :class:`Segments`
``noise-removal``         ``apply(points (N, 2))``                                        :class:`NoiseResult`
``clustering``            ``apply(points (N, 2))``                                        :class:`Clusters`
``straight-line``         ``apply(points (N, 2), groups (N,) | None)``                    :class:`Lines`
``scan-matching``         ``apply(reference (M, 2), current (N, 2), initial: Pose2D)``    :class:`Match`
========================  ==============================================================  ==============

Point-based kernels ignore non-finite input rows (they are noise); they accept read-only arrays.
"""

from __future__ import annotations

import inspect
import weakref
from abc import ABC, abstractmethod
from collections.abc import Mapping
from enum import StrEnum
from typing import Any, ClassVar, Generic, Literal, TypeVar, cast

from numpy.typing import ArrayLike

from shared.kernels.params import KernelParams, validate_params
from shared.kernels.results import Clusters, Lines, Match, NoiseResult, Segments
from shared.kernels.versions import parse_version
from shared.types import Pose2D, Scan

__all__ = [
    "ClusteringKernel",
    "Kernel",
    "NoiseRemovalKernel",
    "ScanMatchingKernel",
    "SegmentationKernel",
    "Stage",
    "StraightLineKernel",
    "parse_version",
    "takes_spacing",
]

P = TypeVar("P", bound=KernelParams)


class Stage(StrEnum):
    """Pipeline stages in processing order (docs/design.md §4)."""

    SEGMENTATION = "segmentation"
    NOISE_REMOVAL = "noise-removal"
    CLUSTERING = "clustering"
    STRAIGHT_LINE = "straight-line"
    SCAN_MATCHING = "scan-matching"


class Kernel(ABC, Generic[P]):
    """Base of all kernels. Subclasses set ``stage``, ``name``, ``version`` and ``Params``.

    Construct with a params model, a plain mapping, keyword overrides, or nothing (defaults)::

        Dbscan({"epsilon_m": 0.05}) == Dbscan(epsilon_m=0.05)
    """

    stage: ClassVar[Stage]
    name: ClassVar[str]
    version: ClassVar[str] = "1.0.0"
    Params: ClassVar[type[KernelParams]]

    def __init__(self, params: P | Mapping[str, Any] | None = None, /, **overrides: Any) -> None:
        values: dict[str, Any] = {}
        if isinstance(params, KernelParams):
            values.update(params.model_dump())
        elif params is not None:
            values.update(params)
        values.update(overrides)
        self._params = cast(P, validate_params(self.name, self.Params, values))

    @property
    def params(self) -> P:
        """The validated, immutable parameters."""
        return self._params

    def get_params(self) -> dict[str, Any]:
        """Parameters as a plain JSON-compatible dict; ``type(k)(k.get_params())`` rebuilds ``k``."""
        return self._params.model_dump(mode="json")

    def with_params(self, **changes: Any) -> Kernel[P]:
        """A new kernel of the same type with some parameters changed (validated)."""
        return type(self)({**self.get_params(), **changes})

    @classmethod
    def param_schema(cls) -> dict[str, Any]:
        """JSON Schema of the parameters (units and ranges included), for the dashboard."""
        return cls.Params.model_json_schema()

    @classmethod
    def ident(cls) -> str:
        """``stage/name@version``."""
        return f"{cls.stage}/{cls.name}@{cls.version}"

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.get_params().items())
        return f"{type(self).__name__}({args})"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Kernel) and type(other) is type(self) and other._params == self._params

    def __hash__(self) -> int:
        return hash((type(self), self._params))


class SegmentationKernel(Kernel[P], ABC):
    """Splits one scan into segments of consecutive returns (paper §3.1)."""

    stage = Stage.SEGMENTATION

    @abstractmethod
    def apply(self, scan: Scan) -> Segments:
        """Segment ``scan``."""


class NoiseRemovalKernel(Kernel[P], ABC):
    """Removes noise points from a point set (paper §3.2).

    A kernel whose class sets ``uses_spacing = True`` and whose ``apply`` has a ``spacing_m`` parameter is
    also given each point's beam spacing (its range times the scanner's angular step, metres) as
    ``apply(points, spacing_m=...)`` where the caller knows it (see :func:`takes_spacing`); every other
    kernel is called as ``apply(points)``, so a subclass that overrides ``apply(points)`` keeps working.
    """

    stage = Stage.NOISE_REMOVAL
    uses_spacing: ClassVar[bool] = False

    @abstractmethod
    def apply(self, points: ArrayLike) -> NoiseResult:
        """Filter ``points`` ``(N, 2)``, metres."""


class ClusteringKernel(Kernel[P], ABC):
    """Partitions points into clusters with centroids (paper §3.3)."""

    stage = Stage.CLUSTERING

    @abstractmethod
    def apply(self, points: ArrayLike) -> Clusters:
        """Cluster ``points`` ``(N, 2)``, metres."""


class StraightLineKernel(Kernel[P], ABC):
    """Turns ordered points (raw points or cluster centroids) into straight lines (paper §3.4, §4).

    ``groups[i]`` is the group (e.g. segment S^n) of point ``i``; lines never span two groups. Within a
    group the points are in scan order. ``None`` puts every point in group 0.

    ``consumes`` tells the pipeline what to feed: ``"centroids"`` (the clustering stage's centroids, as in
    §3.4: centroid joining, SVD and Hough on centroids) or ``"points"`` (the denoised points, as in §4).
    """

    stage = Stage.STRAIGHT_LINE
    consumes: ClassVar[Literal["points", "centroids"]] = "points"

    @abstractmethod
    def apply(self, points: ArrayLike, groups: ArrayLike | None = None) -> Lines:
        """Extract lines from ``points`` ``(N, 2)``, metres."""


class ScanMatchingKernel(Kernel[P], ABC):
    """Estimates the rigid transform aligning the current scan to a reference scan (paper §6.2.2)."""

    stage = Stage.SCAN_MATCHING

    @abstractmethod
    def apply(self, reference: ArrayLike, current: ArrayLike, initial: Pose2D | None = None) -> Match:
        """The pose mapping ``current`` ``(N, 2)`` onto ``reference`` ``(M, 2)``, starting at ``initial``."""


def takes_spacing(kernel: object) -> bool:
    """Whether ``kernel`` wants the points' beam spacing: its class sets ``uses_spacing`` and its ``apply``
    accepts ``spacing_m`` (a subclass that overrides ``apply(points)`` does not). O(1) after the first call
    per class (the answer is cached by class)."""
    cls = type(kernel)
    known = _TAKES_SPACING.get(cls)
    if known is None:
        apply = getattr(cls, "apply", None)
        known = False
        if getattr(cls, "uses_spacing", False) and apply is not None:
            try:
                known = "spacing_m" in inspect.signature(apply).parameters
            except (TypeError, ValueError):
                known = False
        _TAKES_SPACING[cls] = known
    return known


_TAKES_SPACING: weakref.WeakKeyDictionary[type, bool] = weakref.WeakKeyDictionary()
