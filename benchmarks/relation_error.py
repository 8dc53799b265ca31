"""Relation error (Kümmerle et al. 2009) of the online pipeline on the SLAM benchmark logs.

Maps each log of ``../shared/data`` (beside the repository) with the pipeline, one ``step`` per scan as
``linemap map`` does, and prints per log and variant: scans, throughput (scans/s, reading included, from
the second scan on), the relation error of the trajectory (mean +- std of the translational error per
relation, m), that of the log's raw odometry and the published incremental scan-matching figure.

    .venv/bin/python benchmarks/relation_error.py [--logs aces,fr079,mit] [--variant default] [--jitter K]

The figure is chaotic: a discrete decision (a gate, a keyframe) flipped by a rounding difference moves a
log's mean by up to a fifth. ``--jitter K`` replays each log K more times with every odometry reading
moved by ``k`` nanometres (k = 1..K; far below the encoders' resolution) and prints the lowest, the median
and the highest mean over the K + 1 replays, so that two versions of the code are compared by their spread
and not by one sample each.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.progress import Progress
from rich.table import Table

from shared.io import open_log
from shared.metrics import RelationError, read_relations, relation_error
from shared.pipeline import IcpGate, Pipeline, PipelineConfig
from shared.slam import GraphMapper
from shared.types import Pose2D

__all__ = ["LOGS", "VARIANTS", "LogSpec", "Result", "main", "run"]

DATA = Path(__file__).resolve().parent.parent / ".." / "shared" / "data"


@dataclass(frozen=True, slots=True)
class LogSpec:
    """One benchmark log: its name, files under ``DATA`` and the published scan-matching figure (m)."""

    title: str
    log: str
    relations: str
    published_m: tuple[float, float]


LOGS: dict[str, LogSpec] = {
    "aces": LogSpec("ACES", "aces/aces.clf.gz", "aces/aces.relations", (0.173, 0.614)),
    "fr079": LogSpec("Freiburg 079", "fr079/fr079.clf.gz", "fr079/fr079.relations", (0.258, 0.427)),
    "mit": LogSpec(
        "MIT CSAIL", "mit-csail/mit-csail.clf.gz", "mit-csail/mit-csail.relations", (0.106, 0.325)
    ),
}

#: named pipeline set-ups: the defaults, the scan matching as it was before its rework (IcpGate.legacy),
#: and the defaults with the scan match fused with odometry, or the wall refinement given an odometry prior
#: (:mod:`shared.pipeline.fusion`)
VARIANTS: dict[str, Callable[[], tuple[PipelineConfig, IcpGate]]] = {
    "default": lambda: (PipelineConfig(), IcpGate()),
    "legacy": lambda: (PipelineConfig(), IcpGate.legacy()),
    "fused": lambda: (PipelineConfig(), IcpGate(fuse_odometry=True)),
    "refine": lambda: (PipelineConfig(), IcpGate(refine_with_odometry=True)),
}

#: variants mapped under the keyframe pose graph with loop closure (:mod:`shared.slam`)
LOOP_VARIANTS: dict[str, Callable[[], tuple[PipelineConfig, IcpGate]]] = {
    "loop": lambda: (PipelineConfig(), IcpGate()),
    # as "loop", holding one keyframe scan and three scans per place as the robot does (shared.slam.places)
    "loop-places": lambda: (PipelineConfig(), IcpGate()),
}


@dataclass(frozen=True, slots=True)
class Result:
    """One mapped log: scan count, throughput and the relation errors of the pipeline and of odometry."""

    scans: int
    scans_per_s: float
    pipeline: RelationError
    odometry: RelationError


def run(spec: LogSpec, variant: str, progress: Progress, jitter_m: float = 0.0) -> Result:
    """Map ``spec``'s log with ``variant``, every odometry reading moved by ``jitter_m`` along x (module
    docstring); O(scans x step)."""
    config, gate = {**VARIANTS, **LOOP_VARIANTS}[variant]()
    stamps: list[float] = []
    poses: list[tuple[float, float, float]] = []
    odom: list[tuple[float, float, float]] = []
    task = progress.add_task(f"{spec.title} ({variant})", total=None)
    with open_log(DATA / spec.log) as reader:
        offset = reader.info.laser_offset
        pipeline: Pipeline | GraphMapper = Pipeline(config, laser_offset=offset, icp_gate=gate)
        if variant in LOOP_VARIANTS:
            pipeline = GraphMapper(
                lambda: Pipeline(config, laser_offset=offset, icp_gate=gate), places=variant == "loop-places"
            )
        start = time.perf_counter()
        for scan in reader:
            odo = scan.odometry
            if jitter_m and odo is not None:
                odo = Pose2D(odo.x_m + jitter_m, odo.y_m, odo.theta_rad)
            result = pipeline.step(scan, odo)
            if not stamps:  # the first step compiles the kernels: not throughput
                start = time.perf_counter()
            stamps.append(scan.stamp_s)
            poses.append(result.pose.as_tuple())
            odom.append(scan.odometry.as_tuple() if scan.odometry is not None else (np.nan,) * 3)
            progress.advance(task)
        if isinstance(pipeline, GraphMapper):
            pipeline.graph.optimise_batch()
            poses = [tuple(row[1:]) for row in pipeline.trajectory()]
            progress.console.log(
                f"{spec.title}: {len(pipeline.keyframes)} keyframes, {len(pipeline.closures)} loop closures "
                f"of {pipeline.candidates_tried} candidates; {pipeline.places.keyframes_retired} keyframes "
                f"and {pipeline.places.scans_retired} scans retired"
            )
        else:
            pipeline.flush()
        seconds = time.perf_counter() - start
    progress.remove_task(task)
    relations = read_relations(DATA / spec.relations)
    t = np.asarray(stamps)
    return Result(
        len(stamps),
        (len(stamps) - 1) / seconds if seconds > 0 else 0.0,
        relation_error(t, np.asarray(poses), relations),
        relation_error(t, np.asarray(odom), relations),
    )


def _pm(mean: float, std: float) -> str:
    return f"{mean:.3f} +- {std:.3f}"


def main(argv: list[str] | None = None) -> int:
    """Command line: map the chosen logs with the chosen variants and print the table."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--logs", default=",".join(LOGS), help=f"comma-separated, of {', '.join(LOGS)}")
    names = [*VARIANTS, *LOOP_VARIANTS]
    parser.add_argument("--variant", default="default", help=f"comma-separated, of {', '.join(names)}")
    parser.add_argument(
        "--jitter", type=int, default=0, help="K more replays per log, odometry moved by k nm (k = 1..K)"
    )
    args = parser.parse_args(argv)
    if not 0 <= args.jitter <= 20:
        parser.error(f"--jitter {args.jitter}: expected 0 to 20 replays")
    logs = [name.strip() for name in args.logs.split(",") if name.strip()]
    variants = [name.strip() for name in args.variant.split(",") if name.strip()]
    known = [(n, list(LOGS)) for n in logs] + [(v, names) for v in variants]
    for name, choices in known:
        if name not in choices:
            parser.error(f"unknown name {name!r}: expected one of {', '.join(choices)}")
    console = Console(width=140)
    table = Table(title="Relation error (Kümmerle et al. 2009), translational, m")
    columns = ["log", "variant", "scans", "scans/s", "ours", "max", "raw odometry", "published ISM"]
    if args.jitter:
        columns.append(f"mean over {args.jitter + 1} jittered: low / median / high")
    for column in columns:
        table.add_column(column, justify="right" if column in ("scans", "scans/s", "max") else "left")
    with Progress(console=console, transient=True) as progress:
        for name in logs:
            spec = LOGS[name]
            for variant in variants:
                r = run(spec, variant, progress)
                p, o = r.pipeline, r.odometry
                extra = []
                if args.jitter:
                    means = [p.trans_mean_m] + [
                        run(spec, variant, progress, k * 1e-9).pipeline.trans_mean_m
                        for k in range(1, args.jitter + 1)
                    ]
                    extra = [f"{min(means):.3f} / {float(np.median(means)):.3f} / {max(means):.3f}"]
                table.add_row(
                    spec.title,
                    variant,
                    f"{r.scans:,}",
                    f"{r.scans_per_s:.0f}",
                    _pm(p.trans_mean_m, p.trans_std_m),
                    f"{p.trans_max_m:.2f}",
                    _pm(o.trans_mean_m, o.trans_std_m),
                    _pm(*spec.published_m),
                    *extra,
                )
    console.print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
