"""What each stage's kernels are given on real scans, built by the pipeline's own stage functions.

The agent's dry run applies a downloaded kernel to these inputs before it may run
(``robot_agent.kernels.dryrun``): the earlier stages run with the kernels of a configuration (the default
pipeline unless one is given) and the same functions the pipeline's step uses
(:func:`~shared.pipeline.stages.remove_noise`, :func:`~shared.pipeline.stages.cluster`,
:func:`~shared.pipeline.stages.centroids_in_order`), so a kernel is tried on what it will see. Points stay in
the scanner's frame (metres). Pure: scans in, arrays out.

Cost: one segmentation per scan, plus the noise chain and clustering for the later stages; a few
milliseconds per URG-04LX scan.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from shared.kernels import Stage
from shared.pipeline.config import PipelineConfig
from shared.pipeline.stages import Chunk, centroids_in_order, cluster, remove_noise
from shared.types import Pose2D, Scan

__all__ = ["stage_inputs"]

Inputs = list[tuple[tuple[Any, ...], int]]


def stage_inputs(stage: Stage | str, scans: Sequence[Scan], config: PipelineConfig | None = None) -> Inputs:
    """``(apply args, n_in)`` per scan for ``stage``, ``n_in`` being the input rows.

    segmentation: the scan; noise-removal: the scan's segment points; clustering: those points after the
    noise chain; straight-line: per scan two forms, ``(points, groups)`` then the clustering's centroids in
    order with their groups (a kernel takes the form it consumes); scan-matching: each scan's points
    against the previous scan's, from the odometry between them (one scan alone: against a copy of itself
    moved by :data:`~shared.kernels.probes.MOTION`). No scans: a simulated room scan stands in.
    """
    from shared.kernels.probes import moved_copy, room_scan

    stage = Stage(stage)
    scans = list(scans) or [room_scan()]
    kernels = (config or PipelineConfig()).build()
    clusterer: Any = kernels[Stage.CLUSTERING][0]
    with_k = lambda k: clusterer.with_params(n_clusters=k)  # noqa: E731
    out: Inputs = []
    previous: tuple[Scan, Any] | None = None
    for scan in scans:
        if stage == Stage.SEGMENTATION:
            out.append(((scan,), len(scan.ranges_m)))
            continue
        seg: Any = kernels[Stage.SEGMENTATION][0].apply(scan)  # type: ignore[attr-defined]
        pts = np.asarray(seg.points)
        if stage == Stage.NOISE_REMOVAL:
            out.append(((pts,), len(pts)))
        elif stage == Stage.SCAN_MATCHING:
            if previous is None:
                if len(scans) == 1:
                    out.append(((pts, moved_copy(pts), Pose2D()), len(pts)))
            else:
                prev_scan, prev_pts = previous
                initial = Pose2D()
                if prev_scan.odometry is not None and scan.odometry is not None:
                    initial = prev_scan.odometry.between(scan.odometry)
                out.append(((prev_pts, pts, initial), len(pts)))
            previous = (scan, pts)
        else:
            clean = remove_noise(kernels[Stage.NOISE_REMOVAL], Chunk.of(pts, np.asarray(seg.labels)))
            if stage == Stage.CLUSTERING:
                out.append(((clean.points,), len(clean.points)))
                continue
            out.append(((clean.points, clean.groups), len(clean.points)))
            clustered = cluster(clusterer, clean, with_k, min_per_wall=2)
            cents, cgroups = centroids_in_order(clustered)
            out.append(((cents, cgroups), len(cents)))
    return out
