"""``linemap bench worlds``: map every case of the scenario suite offline and measure it (docs/design.md §5).

Each case (:func:`shared.sim.worlds.simulate_case`) is mapped by the same offline path as ``linemap map
sim`` (:func:`shared.mapping.map_scans` with the default :class:`PipelineConfig`), then measured:

- mean / p95 wall error and spurious share: the map against every true wall at the end of the run
  (:func:`shared.metrics.line_accuracy`);
- completeness: the share of the *seen* parts of the true walls with a map segment within 5 cm (a wall
  behind the scanner, beyond its range or of glass cannot be mapped, so it does not count against it);
- walls mapped vs true walls seen (a doubled or hatched wall shows as a ratio well above 1);
- absolute trajectory error of the pipeline's poses and, beside it, of the odometry alone;
- throughput (scans/s, reading included, as ``linemap map`` reports it).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from shared.mapping import MapRun, Source, map_scans
from shared.metrics import absolute_trajectory_error, line_accuracy
from shared.pipeline import PipelineConfig
from shared.sim.worlds import KINDS, QUICK_KINDS, CaseRun, simulate_case
from shared.slam import LoopClosureSettings
from shared.types import FloatArray

__all__ = ["QUICK_MAX_SCANS", "WorldResult", "measure_map", "run_case", "run_worlds", "summarize"]

#: ``--quick`` maps at most this many scans per case.
QUICK_MAX_SCANS = 150


@dataclass(frozen=True, slots=True)
class WorldResult:
    """The figures of one case (lengths in metres, shares 0..1)."""

    kind: str
    seed: int
    odometry: str
    drive: str
    scans: int
    mean_error_m: float
    p95_error_m: float
    completeness: float
    spurious_share: float
    walls_mapped: int
    walls_seen: int
    ate_m: float
    odometry_ate_m: float
    scans_per_s: float
    step_median_ms: float

    @property
    def wall_ratio(self) -> float:
        """Walls mapped per true wall seen (NaN if none was seen)."""
        return self.walls_mapped / self.walls_seen if self.walls_seen else math.nan

    def as_dict(self) -> dict[str, object]:
        """The fields (and ``wall_ratio``) as a plain dict for JSON."""
        return {**asdict(self), "wall_ratio": self.wall_ratio}


def measure_map(case: CaseRun, segments: FloatArray, trajectory: FloatArray) -> dict[str, float | int]:
    """The accuracy figures of a map of ``case``: ``segments`` ``(L, 4)`` and the robot ``trajectory``
    ``(T, 4)`` rows ``[stamp_s, x_m, y_m, theta_rad]`` (NaN trajectory error unless T is the run's N)."""
    run = case.run
    acc = line_accuracy(segments, run.world.walls)
    seen = line_accuracy(segments, case.seen_walls) if len(case.seen_walls) else None
    truth = run.trajectory("true")[:, 1:]
    traj = np.asarray(trajectory, dtype=np.float64).reshape(-1, 4)
    ate = absolute_trajectory_error(traj[:, 1:], truth).rmse_m if len(traj) == len(truth) else math.nan
    return {
        "mean_error_m": acc.mean_distance_m,
        "p95_error_m": acc.p95_distance_m,
        "completeness": seen.completeness if seen is not None else math.nan,
        "spurious_share": acc.spurious_share,
        "walls_mapped": acc.n_segments,
        "walls_seen": case.walls_seen,
        "ate_m": ate,
        "odometry_ate_m": absolute_trajectory_error(run.trajectory("odometry")[:, 1:], truth).rmse_m,
    }


def run_case(
    case: CaseRun, config: PipelineConfig | None = None, loop_closure: LoopClosureSettings | None = None
) -> tuple[WorldResult, MapRun]:
    """Map ``case`` offline (as ``linemap map`` does; under the pose graph with ``loop_closure``) and
    measure the map with :func:`measure_map`; returns the figures and the mapping run."""
    run = case.run
    name = f"{case.kind} seed {case.seed}"
    source = Source(name, run.scans, run.drive.laser_offset, len(run), run.world, run.trajectory())
    mapped = map_scans(source, config or PipelineConfig(), loop_closure=loop_closure)
    figures = measure_map(case, mapped.snapshot.segments, mapped.snapshot.trajectory)
    result = WorldResult(
        kind=case.kind,
        seed=case.seed,
        odometry=case.odometry,
        drive=case.drive,
        scans=mapped.scans,
        scans_per_s=mapped.scans_per_s,
        step_median_ms=mapped.step_median_ms,
        **figures,  # type: ignore[arg-type]
    )
    return result, mapped


def run_worlds(
    kinds: Sequence[str] | None = None,
    seeds: Sequence[int] = (0, 1, 2),
    *,
    quick: bool = False,
    odometry: str | None = None,
    drive: str | None = None,
    config: PipelineConfig | None = None,
    pictures: Path | None = None,
    progress: Callable[[str, int, int], None] | None = None,
    loop_closure: LoopClosureSettings | None = None,
) -> list[WorldResult]:
    """Run the suite: every kind in ``kinds`` (default: all; ``quick``: :data:`QUICK_KINDS`) with every
    seed, each case capped at :data:`QUICK_MAX_SCANS` scans when ``quick``. ``pictures``: a folder for one
    PNG per case (map over ground truth). ``progress(label, done, total)`` is called before each case and
    once at the end."""
    names = list(kinds) if kinds else list(QUICK_KINDS if quick else KINDS)
    cases = [(k, s) for k in names for s in seeds]
    results = []
    for i, (kind, seed) in enumerate(cases):
        if progress is not None:
            progress(f"{kind} seed {seed}", i, len(cases))
        case = simulate_case(
            kind, seed, odometry=odometry, drive=drive, max_scans=QUICK_MAX_SCANS if quick else None
        )
        result, mapped = run_case(case, config, loop_closure)
        results.append(result)
        if pictures is not None:
            from shared.export import render_map

            pictures.mkdir(parents=True, exist_ok=True)
            title = (
                f"{kind} seed {seed} ({case.odometry}, {case.drive}): {result.mean_error_m * 100:.1f} cm, "
                f"{result.completeness * 100:.0f} % complete, {result.spurious_share * 100:.0f} % spurious"
            )
            render_map(mapped.snapshot, pictures / f"{kind}-{seed}.png", walls=case.truth.walls, title=title)
    if progress is not None:
        progress("done", len(cases), len(cases))
    return results


def _nan(reduce: Callable[[FloatArray], float], values: list[float]) -> float:
    """``reduce`` over the finite ``values`` (NaN if there is none)."""
    arr = np.array(values, dtype=np.float64)
    arr = arr[np.isfinite(arr)]
    return float(reduce(arr)) if len(arr) else math.nan


def _nanmean(values: list[float]) -> float:
    return _nan(np.mean, values)


def summarize(results: Sequence[WorldResult]) -> dict[str, float | int]:
    """The summary row: means over the cases, the worst case of each accuracy figure, and how many cases
    meet the suite's targets (docs/worlds.md) (mean error <= 2 cm, completeness >= 95 %, spurious <= 3 %,
    walls <= 1.5x)."""
    if not results:
        return {"cases": 0}
    rs = list(results)
    meets = [
        r.mean_error_m <= 0.02 and r.completeness >= 0.95 and r.spurious_share <= 0.03 and r.wall_ratio <= 1.5
        for r in rs
    ]
    return {
        "cases": len(rs),
        "scans": sum(r.scans for r in rs),
        "mean_error_m": _nanmean([r.mean_error_m for r in rs]),
        "worst_mean_error_m": _nan(np.max, [r.mean_error_m for r in rs]),
        "p95_error_m": _nanmean([r.p95_error_m for r in rs]),
        "completeness": _nanmean([r.completeness for r in rs]),
        "worst_completeness": _nan(np.min, [r.completeness for r in rs]),
        "spurious_share": _nanmean([r.spurious_share for r in rs]),
        "worst_spurious_share": _nan(np.max, [r.spurious_share for r in rs]),
        "wall_ratio": _nanmean([r.wall_ratio for r in rs]),
        "ate_m": _nanmean([r.ate_m for r in rs]),
        "odometry_ate_m": _nanmean([r.odometry_ate_m for r in rs]),
        "scans_per_s": float(np.median([r.scans_per_s for r in rs])),
        "cases_meeting_targets": int(sum(meets)),
    }
