"""One description per pipeline stage: everything the rest of the code needs to know about a stage.

The pipeline's configuration, the conformance battery, the control message, the agent's kernel checks and
dry run, and the server's dashboard all read :data:`STAGES` instead of keeping their own ``if stage == ...``
ladders. A new stage is one :class:`StageSpec` here (plus its kernel base in :mod:`shared.kernels.base`,
its result type in :mod:`shared.kernels.results` and its checks in :mod:`shared.kernels.checks`), then
its kernels. ``docs/architecture.md`` ("Where per-stage knowledge lives") walks through it.

========================  ============  ================================  ======  ========  =========
stage                     paper         configuration field / element     chain   optional  scheduled
========================  ============  ================================  ======  ========  =========
``segmentation``          §3.1          ``segmentation``                  no      no        no
``noise-removal``         §3.2          ``noise_removal``                 yes     no        yes
``clustering``            §3.3          ``clustering``                    no      no        yes
``straight-line``         §3.4, §4      ``straight_line`` /               no      no        yes
                                        ``<straight-line-method>``
``scan-matching``         §6.2.2        ``scan_matching``                 no      yes       no
========================  ============  ================================  ======  ========  =========
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from shared.kernels import checks
from shared.kernels.base import (
    ClusteringKernel,
    Kernel,
    NoiseRemovalKernel,
    ScanMatchingKernel,
    SegmentationKernel,
    Stage,
    StraightLineKernel,
)
from shared.kernels.probes import moved_copy, points_to_scan
from shared.kernels.results import Clusters, Lines, Match, NoiseResult, Segments
from shared.types import FloatArray, Pose2D

__all__ = ["SCHEDULED", "STAGES", "StageSpec", "spec_of", "stage_of_field"]

#: ``probe(points (N, 2))``: the positional arguments of ``apply`` built from one point set (metres).
Probe = Callable[[FloatArray], tuple[Any, ...]]
#: ``check(result, n_in)``: problems with a result for ``n_in`` input rows.
Check = Callable[[Any, int], list[str]]
#: ``on_wall(kernel, result, points)``: problems with what a kernel found along the wall x = 2 m.
OnWall = Callable[[Any, Any, FloatArray], list[str]]
#: ``on_nonfinite(result, rows)``: problems with how the non-finite input rows ``rows`` came out.
OnNonFinite = Callable[[Any, Sequence[int]], list[str]]


@dataclass(frozen=True, slots=True)
class StageSpec:
    """What a stage is. ``base``: the abstract kernel class its kernels derive from; ``result``: the type
    ``apply`` returns; ``paper``: the paper's section; ``field``: the
    :class:`~shared.pipeline.config.PipelineConfig` field holding its kernel choice; ``element``: the
    control message's element for it (paper Listing 1); ``chain``: several kernels applied in order;
    ``optional``: may be switched off; ``scheduled``: online / offline / mixed scheduling applies (the others
    run on every scan); ``probe``, ``check``, ``on_wall``, ``on_nonfinite``: how the conformance battery
    feeds it and what its results must satisfy (:mod:`shared.kernels.checks`)."""

    stage: Stage
    base: type[Kernel[Any]]
    result: type[Any]
    paper: str
    field: str
    element: str
    probe: Probe
    check: Check
    on_wall: OnWall
    on_nonfinite: OnNonFinite = checks.nothing_more
    chain: bool = False
    optional: bool = False
    scheduled: bool = False

    def as_dict(self) -> dict[str, Any]:
        """The JSON-compatible part (what the server's API and the dashboard read)."""
        return {
            "stage": str(self.stage),
            "paper": self.paper,
            "field": self.field,
            "element": self.element,
            "result": self.result.__name__,
            "chain": self.chain,
            "optional": self.optional,
            "scheduled": self.scheduled,
        }


def _points(points: FloatArray) -> tuple[Any, ...]:
    return (points,)


def _one_group(points: FloatArray) -> tuple[Any, ...]:
    return (points, np.zeros(len(points), dtype=np.intp))


def _pair(points: FloatArray) -> tuple[Any, ...]:
    return (points, moved_copy(points), Pose2D())


def _scan(points: FloatArray) -> tuple[Any, ...]:
    return (points_to_scan(points),)


#: Every stage in processing order (the order of :class:`~shared.kernels.base.Stage`).
STAGES: dict[Stage, StageSpec] = {
    s.stage: s
    for s in (
        StageSpec(
            stage=Stage.SEGMENTATION,
            base=SegmentationKernel,
            result=Segments,
            paper="§3.1",
            field="segmentation",
            element="segmentation",
            probe=_scan,
            check=checks.check_segments,
            on_wall=checks.segments_on_wall,
        ),
        StageSpec(
            stage=Stage.NOISE_REMOVAL,
            base=NoiseRemovalKernel,
            result=NoiseResult,
            paper="§3.2",
            field="noise_removal",
            element="noise-removal",
            probe=_points,
            check=checks.check_noise,
            on_wall=checks.nothing_found_needed,
            on_nonfinite=checks.noise_skip_nonfinite,
            chain=True,
            scheduled=True,
        ),
        StageSpec(
            stage=Stage.CLUSTERING,
            base=ClusteringKernel,
            result=Clusters,
            paper="§3.3",
            field="clustering",
            element="clustering",
            probe=_points,
            check=checks.check_clusters,
            on_wall=checks.clusters_on_wall,
            on_nonfinite=checks.clusters_skip_nonfinite,
            scheduled=True,
        ),
        StageSpec(
            stage=Stage.STRAIGHT_LINE,
            base=StraightLineKernel,
            result=Lines,
            paper="§3.4, §4",
            field="straight_line",
            element="straight-line-method",
            probe=_one_group,
            check=checks.check_lines,
            on_wall=checks.lines_on_wall,
            scheduled=True,
        ),
        StageSpec(
            stage=Stage.SCAN_MATCHING,
            base=ScanMatchingKernel,
            result=Match,
            paper="§6.2.2",
            field="scan_matching",
            element="scan-matching",
            probe=_pair,
            check=checks.check_match,
            on_wall=checks.match_on_wall,
            optional=True,
        ),
    )
}

#: The stages whose schedule the modes govern (the others run on every scan), in order.
SCHEDULED: tuple[Stage, ...] = tuple(s.stage for s in STAGES.values() if s.scheduled)


def spec_of(stage: Stage | str) -> StageSpec:
    """The description of ``stage`` (a :class:`Stage` or its value); ``ValueError`` naming the stages
    otherwise."""
    try:
        return STAGES[Stage(stage)]
    except ValueError:
        raise ValueError(f"unknown stage {stage!r}: expected one of {', '.join(STAGES)}") from None


def stage_of_field(field: str) -> Stage:
    """The stage whose kernel choice is :class:`~shared.pipeline.config.PipelineConfig` field ``field``."""
    for spec in STAGES.values():
        if spec.field == field:
            return spec.stage
    fields = ", ".join(s.field for s in STAGES.values())
    raise ValueError(f"unknown stage field {field!r}: expected one of {fields}")
