"""Multi-lap runs: the map after each lap and the position error over time, with and without loop closure.

A world driven in laps (``loop-block``: a loop of corridors round a block, 42-62 m a lap, worn-wheel
odometry with a scale and heading bias) is mapped as the robot maps it, one scan at a time: by the front end
alone (:class:`~shared.pipeline.Pipeline`) and under the pose graph (:class:`~shared.slam.OnlineGraphMapper`
with its search and redraws in the step, so the run is deterministic). At the end of each lap the map the
robot shows then is measured against the truth (:func:`shared.bench.worlds.measure_map`); at every step the
position the robot believed then is compared with the true one (the paper's Fig. 20, position error over
time). The time of each pose-graph optimisation and of each redraw is kept.

Cost: O(laps x scans x step); about 10 s a lap with loop closure on this machine.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from shared.bench.worlds import measure_map
from shared.metrics import absolute_trajectory_error
from shared.pipeline import Pipeline, PipelineConfig
from shared.sim.worlds import CaseRun, simulate_case
from shared.slam import LoopClosureSettings, OnlineGraphMapper
from shared.types import FloatArray

__all__ = ["LapFigures", "LapsRun", "lap_ends", "run_laps", "run_laps_suite"]

VARIANTS = ("front end", "loop closure")


@dataclass(frozen=True, slots=True)
class LapFigures:
    """The map as the robot showed it at the end of lap ``lap`` (1-based), against the truth; ``ate_m``
    is the RMS error of the positions believed so far (at the time of each step)."""

    lap: int
    scans: int
    mean_error_m: float
    p95_error_m: float
    completeness: float
    spurious_share: float
    walls_mapped: int
    walls_seen: int
    ate_m: float

    @property
    def wall_ratio(self) -> float:
        """Walls mapped per true wall seen."""
        return self.walls_mapped / self.walls_seen if self.walls_seen else math.nan

    def meets_targets(self) -> bool:
        """The multi-lap targets (docs/loopclosure.md): <= 2 cm, >= 95 % complete, <= 3 % spurious, <= 1.5x
        walls."""
        return (
            self.mean_error_m <= 0.02
            and self.completeness >= 0.95
            and self.spurious_share <= 0.03
            and self.wall_ratio <= 1.5
        )


@dataclass(frozen=True, slots=True)
class LapsRun:
    """One world and seed mapped one way (``variant``: ``"front end"`` or ``"loop closure"``).

    ``stamps_s`` / ``position_error_m`` ``(N,)``: each step's time and the distance (m) between the
    position the robot believed then and the true one; ``odometry_error_m`` the same for raw odometry.
    ``optimise_ms`` the pose-graph optimisations (an iSAM2 update at every keyframe and after closures),
    ``redraw_ms`` the redraws of the shown map, ``step_ms`` every step (search and redraws included: they
    run in the step here)."""

    kind: str
    seed: int
    variant: str
    laps: tuple[LapFigures, ...]
    stamps_s: FloatArray
    position_error_m: FloatArray
    odometry_error_m: FloatArray
    lap_end_s: tuple[float, ...]
    closures: int = 0
    optimise_ms: tuple[float, ...] = field(default=())
    redraw_ms: tuple[float, ...] = field(default=())
    step_ms: tuple[float, ...] = field(default=())


def lap_ends(case: CaseRun, laps: int) -> list[int]:
    """Index of the first scan after each lap's end (the last one is the run's length): a lap ends where
    the true path has covered that many times the closed path's length. O(N)."""
    knots = np.asarray(case.scene.knots, dtype=np.float64)
    lap_m = float(np.sum(np.hypot(*np.diff(knots, axis=0).T)))
    truth = np.asarray([(p.x_m, p.y_m) for p in case.run.true_poses], dtype=np.float64)
    travelled = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(truth, axis=0).T))])
    ends = [int(np.searchsorted(travelled, k * lap_m - 1e-6)) + 1 for k in range(1, laps)]
    return [min(e, len(truth)) for e in ends] + [len(truth)]


def _figures(case: CaseRun, lap: int, n: int, segments: FloatArray, believed: FloatArray) -> LapFigures:
    m = measure_map(case, segments, np.zeros((0, 4)))
    truth = case.run.trajectory("true")[:n, 1:]
    ate = absolute_trajectory_error(believed[:n], truth).rmse_m
    return LapFigures(
        lap,
        n,
        float(m["mean_error_m"]),
        float(m["p95_error_m"]),
        float(m["completeness"]),
        float(m["spurious_share"]),
        int(m["walls_mapped"]),
        int(m["walls_seen"]),
        float(ate),
    )


def run_laps(
    case: CaseRun, laps: int, loop_closure: LoopClosureSettings | None, config: PipelineConfig | None = None
) -> LapsRun:
    """Map ``case`` (driven ``laps`` times) one scan at a time and measure it at each lap's end."""
    run = case.run
    config = config or PipelineConfig()
    offset = run.drive.laser_offset
    mapper: Pipeline | OnlineGraphMapper
    if loop_closure is None:
        mapper = Pipeline(config, laser_offset=offset)
    else:
        mapper = OnlineGraphMapper(
            lambda c: Pipeline(c, laser_offset=offset), config, loop_closure, worker=False
        )
    ends = lap_ends(case, laps)
    believed = np.zeros((len(run.scans), 3))
    step_ms: list[float] = []
    figures: list[LapFigures] = []
    for i, scan in enumerate(run.scans):
        t0 = time.perf_counter()
        pose = mapper.step(scan).pose
        step_ms.append((time.perf_counter() - t0) * 1e3)
        believed[i] = pose.as_tuple()
        if i + 1 in ends:
            mapper.flush()
            snap = mapper.snapshot()
            figures.append(_figures(case, len(figures) + 1, i + 1, snap.segments, believed))
    truth = run.trajectory("true")
    odometry = run.trajectory("odometry")
    closures = 0
    optimise: tuple[float, ...] = ()
    redraw: tuple[float, ...] = ()
    if isinstance(mapper, OnlineGraphMapper):
        closures = mapper.closures
        optimise = tuple(mapper.optimise_ms)
        redraw = tuple(mapper.redraw_ms)
        mapper.close()
    return LapsRun(
        case.kind,
        case.seed,
        VARIANTS[loop_closure is not None],
        tuple(figures),
        truth[:, 0].copy(),
        np.hypot(*(believed[:, :2] - truth[:, 1:3]).T),
        np.hypot(*(odometry[:, 1:3] - truth[:, 1:3]).T),
        tuple(float(truth[min(e, len(truth)) - 1, 0]) for e in ends),
        closures,
        optimise,
        redraw,
        tuple(step_ms),
    )


def run_laps_suite(
    seeds: Sequence[int],
    laps: int = 3,
    *,
    kind: str = "loop-block",
    loop_closure: LoopClosureSettings | None = None,
    progress: Callable[[str, int, int], None] | None = None,
) -> list[LapsRun]:
    """Every seed of ``kind`` driven ``laps`` times, front end alone then with loop closure (default
    settings unless given); ``progress(label, done, total)`` before each run and once at the end."""
    settings = loop_closure or LoopClosureSettings()
    jobs = [(seed, lc) for seed in seeds for lc in (None, settings)]
    out: list[LapsRun] = []
    case: CaseRun | None = None
    for i, (seed, lc) in enumerate(jobs):
        if progress is not None:
            progress(f"{kind} seed {seed}, {VARIANTS[lc is not None]}", i, len(jobs))
        if case is None or case.seed != seed:
            case = simulate_case(kind, seed, laps=laps)
        out.append(run_laps(case, laps, lc))
    if progress is not None:
        progress("done", len(jobs), len(jobs))
    return out
