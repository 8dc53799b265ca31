"""The step loop (docs/design.md §2-§4): one ``step(scan)`` at a time, from a scan and odometry to the line
map.

Per step: pose prediction from odometry (paper §2, eq. 9-11), ICP correction against a recent keyframe
scan (§6.2.2; :class:`~shared.pipeline.gate.IcpGate` says when it is believed, :mod:`shared.pipeline.rematch`
gives a refused match a second chance) and refinement against a local wall map
(:mod:`shared.pipeline.localize`), segmentation (§3.1) of the scan, then the scheduled stages (noise removal
§3.2, clustering §3.3, straight lines §3.4/§4) and the map update. In **online** mode the scheduled stages
run on every step's new points; in **offline** mode points accumulate for ``n_smax`` steps (flushed early
once the heading turned more than ``heading_flush_deg`` since the batch began); in **mixed** mode each stage
has its own schedule.
Every point passes each stage exactly once: a stage's buffer is emptied when it runs.

The pipeline is stateful (it is the robot's memory); the kernels it calls are pure.
"""

from __future__ import annotations

import copy
import logging
import math
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from shared.errors import LinemapError
from shared.kernels import Stage
from shared.pipeline.censoring import censored_returns
from shared.pipeline.config import SCHEDULED, Mode, PipelineConfig
from shared.pipeline.freespace import FreeSpace
from shared.pipeline.gate import IcpGate
from shared.pipeline.odonoise import OdometryNoise
from shared.pipeline.rangenoise import NO_RANGE_NOISE, RangeNoise, range_noise_for
from shared.pipeline.regroup import regroup
from shared.pipeline.seenfree import SeenFree
from shared.pipeline.snapshot import MapSnapshot
from shared.pipeline.stages import (
    Chunk,
    cluster,
    concat,
    extract_lines_grouped,
    line_uncertainty,
    noise_floored_uncertainty,
    remove_noise,
)
from shared.pipeline.state import MapperState
from shared.pipeline.tracker import PoseTracker
from shared.pipeline.wallmap import MergeTolerances, WallMap
from shared.protocol.trajectory import thin_positions
from shared.types import FloatArray, IntArray, Pose2D, Scan, wrap_angle

__all__ = ["KEPT_CENTROID_BATCHES", "IcpGate", "MapState", "Pipeline", "StepResult"]

log = logging.getLogger(__name__)


#: the newest batches of centroids a pipeline with a bounded ``history`` keeps at least (one a step online,
#: some 17 centroids each on the simulated world; :meth:`Pipeline.recent_centroids` is asked for 200)
KEPT_CENTROID_BATCHES = 256


@dataclass(frozen=True, slots=True)
class StepResult:
    """What one step did: the new pose, whether ICP corrected it, which stages ran, the map version."""

    version: int
    pose: Pose2D
    icp_used: bool
    ran: tuple[Stage, ...]
    step_ms: float


@dataclass(slots=True)
class _Buffer:
    chunks: list[Chunk] = field(default_factory=list)
    steps: int = 0
    heading0: float | None = None


@dataclass(frozen=True, slots=True)
class MapState:
    """A pipeline's shown map at one moment (:meth:`Pipeline.map_state`): opaque outside the pipeline."""

    parts: tuple[Any, Any, Any]  # the wall map, its free-space evidence, the points seen free
    centroids: tuple[FloatArray, ...]
    trajectory: tuple[tuple[float, float, float, float], ...]
    next_group: int


class Pipeline:
    """Maps scans one step at a time. ``snapshot()`` gives the temporary map after any step.

    ``history``: the poses the trajectory keeps (None: every one, as mapping a log offline wants). A robot
    mapping for days sets it (the agent: :data:`shared.protocol.MAX_TRAJECTORY_POSES`): the trajectory is
    thinned by the rule the Robot DB and the server apply, and the centroids keep the newest
    :data:`KEPT_CENTROID_BATCHES` batches, so the pipeline's memory and saved state do not grow with the
    run."""

    def __init__(
        self,
        config: PipelineConfig | None = None,
        *,
        laser_offset: Pose2D | None = None,
        merge: MergeTolerances | None = None,
        icp_gate: IcpGate | None = None,
        range_noise: RangeNoise | None = None,
        timing_window: int = 1000,
        track_only: bool = False,
        history: int | None = None,
    ) -> None:
        if history is not None and history < 2:
            raise LinemapError(f"history = {history}: expected at least 2 poses, or None to keep all")
        self._config = config or PipelineConfig()
        # what the trajectory and centroids keep (None: all, e.g. mapping a log offline; a robot mapping
        # for days keeps a bounded history so that its memory and saved state do not grow with the run)
        self._history = history
        # poses only: no shown map (a pose graph draws it later from its corrected poses, shared.slam)
        self.track_only = track_only
        # typed Any: each stage's kernels are driven through that stage's own apply signature
        self._kernels: dict[Stage, list[Any]] = dict(self._config.build())
        self._offset = laser_offset or Pose2D()
        self._gate = icp_gate or IcpGate()
        # the scanner's range noise (None: read from each scan's range window, shared.pipeline.rangenoise)
        self._range_noise = range_noise
        self._noise = range_noise or NO_RANGE_NOISE
        self._map = WallMap(merge)
        self._freespace = FreeSpace()  # walls later seen through leave the map
        self._seen_free = SeenFree()  # points where earlier beams passed through stay out of the shown map
        # Localisation keeps local line maps of its own (shared.pipeline.tracker); the configured stages
        # make the map shown.
        self._tracker = PoseTracker(self._offset, self._gate, merge)
        self._centroids: list[FloatArray] = []
        self._trajectory: list[tuple[float, float, float, float]] = []
        self._points: FloatArray = np.zeros((0, 2))  # the last scan's returns the pose took (scanner frame)
        self._next_group = 0
        self._version = 0
        self._stamp = 0.0
        self._buffers: dict[Stage, _Buffer] = {s: _Buffer() for s in SCHEDULED}
        self._step_ms: deque[float] = deque(maxlen=timing_window)
        self._by_k: dict[int, Any] = {}

    # ------------------------------------------------------------------ configuration
    @property
    def config(self) -> PipelineConfig:
        """The configuration in force."""
        return self._config

    def reconfigure(self, config: PipelineConfig) -> None:
        """Swap in a new configuration between steps. Kernels are built (validated) first; on any error the
        old configuration stays in force and the error propagates. Pending batches are kept and run under
        the new schedule."""
        kernels: dict[Stage, list[Any]] = dict(config.build())
        self._config, self._kernels = config, kernels
        self._by_k = {}
        log.info("pipeline reconfigured: mode=%s", config.mode)

    # ------------------------------------------------------------------ stepping
    def step(self, scan: Scan, odometry: Pose2D | None = None, *, pose: Pose2D | None = None) -> StepResult:
        """Process one scan; ``odometry`` (robot pose from the wheels) defaults to ``scan.odometry``.

        ``pose`` (world frame) fixes the robot pose instead of estimating it: mapping with known poses, as
        a pose graph's corrected trajectory gives them (:mod:`shared.slam`); the localisation maps are
        then left alone."""
        t0 = time.perf_counter()
        odom = odometry if odometry is not None else scan.odometry
        seg = self._kernels[Stage.SEGMENTATION][0].apply(scan)
        noise = self._range_noise if self._range_noise is not None else range_noise_for(scan)
        self._noise = noise  # for the map update (a scanner's range noise does not change within a log)
        points, labels = seg.points, np.asarray(seg.labels)
        # returns near the range limit are biased short (shared.pipeline.censoring): neither the pose nor
        # the map takes them; the robot sees the surface properly a few centimetres later
        censored = censored_returns(scan, seg.beam_index, noise)
        if censored.any():
            points, labels = points[~censored], labels[~censored]
        self._points = points
        tracker = self._tracker
        if pose is None:
            matchers = self._kernels[Stage.SCAN_MATCHING]
            icp_used = tracker.estimate(odom, points, noise, matchers, self._seen_free)
        else:
            tracker.hold(pose, odom)
            icp_used = False
        now = tracker.pose
        assert now is not None
        laser = now @ self._offset
        world = laser.transform_points(points) if len(points) else np.zeros((0, 2))
        groups = np.where(labels >= 0, labels + self._next_group, -1).astype(np.intp)
        self._next_group += seg.n_segments
        if pose is None:
            tracker.add_lines(world, groups)
        # each return's beam spacing (range x angular step): how far apart a wall's returns lie there,
        # which noise removal's neighbourhood follows on scanners coarser than the paper's URG-04LX
        spacing = np.hypot(points[:, 0], points[:, 1]) * abs(scan.angle_increment_rad)
        if not self.track_only:
            moved = self._seen_free.moved(world)  # in space seen free before: not walls (yet)
            if moved.any():
                world, groups, spacing = world[~moved], groups[~moved], spacing[~moved]
        self._seen_free.observe(laser, scan)
        if not self.track_only:
            self._freespace.observe(self._map, laser, scan)
        self._stamp = scan.stamp_s
        self._trajectory.append((scan.stamp_s, now.x_m, now.y_m, now.theta_rad))
        if self._history is not None and len(self._trajectory) > self._history:
            self._forget_history(self._history)
        ran: tuple[Stage, ...] = ()
        if not self.track_only:
            ran = self._feed(Chunk.of(world, groups, (laser.x_m, laser.y_m), spacing), final=False)
        self._version += 1
        elapsed = (time.perf_counter() - t0) * 1e3
        self._step_ms.append(elapsed)
        return StepResult(self._version, now, icp_used, ran, elapsed)

    def _forget_history(self, keep: int) -> None:
        """Thin the trajectory to ``keep`` poses by the rule the Robot DB and the server apply (every recent
        pose, ever sparser older ones: :func:`shared.protocol.trajectory.thin_positions`). O(keep), once
        per about ``keep // 4`` steps."""
        drop = set(thin_positions(len(self._trajectory), keep))
        self._trajectory = [p for i, p in enumerate(self._trajectory) if i not in drop]

    def flush(self) -> tuple[Stage, ...]:
        """Run every pending batch now (end of a log, or before a mode change)."""
        ran = self._feed(None, final=True)
        if ran:
            self._version += 1
        return ran

    # ------------------------------------------------------------------ scheduled stages
    def _ready(self, stage: Stage, buf: _Buffer, final: bool) -> bool:
        if not buf.chunks:
            return False
        sched = self._config.stage_schedule(stage)
        if final or sched.mode == Mode.ONLINE:
            return True
        if buf.steps >= sched.n_smax:
            return True
        turned = abs(wrap_angle(self.pose.theta_rad - (buf.heading0 or 0.0)))
        return turned > math.radians(self._config.heading_flush_deg)

    def _feed(self, chunk: Chunk | None, final: bool) -> tuple[Stage, ...]:
        """Push a step's chunk through the scheduled stages, running each one whose batch is ready."""
        ran: list[Stage] = []
        for stage in SCHEDULED:
            buf = self._buffers[stage]
            if chunk is not None:
                if not buf.chunks:
                    buf.heading0 = self.pose.theta_rad
                buf.chunks.append(chunk)
                buf.steps += chunk.steps
            if not self._ready(stage, buf, final):
                chunk = None
                continue
            batch = concat(buf.chunks)
            self._buffers[stage] = _Buffer()
            chunk = self._run(stage, batch)
            ran.append(stage)
        return tuple(ran)

    def _run(self, stage: Stage, batch: Chunk) -> Chunk | None:
        kernels = self._kernels[stage]
        try:
            if stage == Stage.NOISE_REMOVAL:
                return remove_noise(kernels, batch)
            if stage == Stage.CLUSTERING:
                if batch.steps > 1:  # an offline batch: one group per wall, not per scan
                    walls = regroup(batch.points, batch.groups)
                    walls = np.where(walls >= 0, walls + self._next_group, -1)  # ids stay unique
                    if (walls >= 0).any():
                        self._next_group = int(walls.max()) + 1
                    batch = Chunk(
                        batch.points,
                        walls,
                        batch.centroids,
                        batch.centroid_groups,
                        batch.steps,
                        batch.viewpoint,
                    )
                line_kernel = self._kernels[Stage.STRAIGHT_LINE][0]
                needs_two = getattr(line_kernel, "consumes", "points") == "centroids"
                out = cluster(kernels[0], batch, self._clusterer_with_k, min_per_wall=2 if needs_two else 0)
                if len(out.centroids):
                    self._centroids.append(out.centroids)
                    if self._history is not None and len(self._centroids) > 2 * KEPT_CENTROID_BATCHES:
                        del self._centroids[:-KEPT_CENTROID_BATCHES]
                return out
            segments, seg_groups = extract_lines_grouped(kernels[0], batch)
            sigmas, direction_sds = line_uncertainty(segments, seg_groups, batch)
            # a noisy piece that a wall of the map explains within the range noise (tilted past the
            # merge's angle test, but not past three standard deviations of its own direction) may join
            # a wall but not start one: such pieces started the short walls crossing the demo's at
            # 10-35 degrees ("hatching", docs/worlds.md)
            scatter, honest = noise_floored_uncertainty(segments, batch, sigmas, direction_sds, self._noise)
            band = np.maximum(self._map.tol.offset_tol_m, 3.0 * scatter)
            explained = self._map.explained(segments, honest, band, viewpoint=batch.viewpoint)
            self._map.add_segments(
                segments,
                observations=batch.steps,
                viewpoint=batch.viewpoint,
                sigmas_m=sigmas,
                direction_sds_rad=direction_sds,
                may_create=~explained,
            )
            return None
        except LinemapError:
            raise
        except Exception as exc:  # a kernel that raises must not take the robot down
            kernel = kernels[0] if kernels else None
            raise LinemapError(
                f"kernel {kernel.ident() if kernel else stage} failed on {len(batch.points)} points: "
                f"{type(exc).__name__}: {exc}"
            ) from exc

    def _clusterer_with_k(self, k: int) -> Any:
        """The clustering kernel in force with ``n_clusters = k`` (cached per k until reconfigured)."""
        cached = self._by_k.get(k)
        if cached is None:
            cached = self._kernels[Stage.CLUSTERING][0].with_params(n_clusters=k)
            self._by_k[k] = cached
        return cached

    # ------------------------------------------------------------------ the map
    @property
    def version(self) -> int:
        """Increases with every step (and every flush that ran a stage)."""
        return self._version

    @property
    def scan_points(self) -> FloatArray:
        """The last step's returns that the pose estimate took ``(N, 2)``: scanner frame, metres, beam
        order, returns biased by the range limit left out (:mod:`shared.pipeline.censoring`). O(1)."""
        return self._points

    @property
    def gate(self) -> IcpGate:
        """The scan-match gate and odometry noise figures in force."""
        return self._gate

    @property
    def laser_offset(self) -> Pose2D:
        """The scanner's pose in the robot frame."""
        return self._offset

    @property
    def range_noise(self) -> RangeNoise:
        """The scanner's range noise model in force (read from the last scan unless given)."""
        return self._noise

    @property
    def pose(self) -> Pose2D:
        """The current robot pose (world frame)."""
        return self._tracker.pose or Pose2D()

    @property
    def odometry_noise(self) -> OdometryNoise:
        """How noisy the odometry is, learned from the believed scan matches."""
        return self._tracker.odometry_noise

    @property
    def icp_rejections(self) -> int:
        """Scan matches the gate refused (and no second chance saved)."""
        return self._tracker.icp_rejections

    @property
    def map_refinements(self) -> int:
        """Poses the refinement against the local wall map moved."""
        return self._tracker.map_refinements

    @property
    def rematches(self) -> int:
        """Refused scan matches a second chance saved."""
        return self._tracker.rematches

    @property
    def local_map_restarts(self) -> int:
        """How often a local wall map was restarted."""
        return self._tracker.local_map_restarts

    def timing_ms(self) -> tuple[float, float]:
        """Median and 99th percentile of recent step times, in milliseconds."""
        if not self._step_ms:
            return (0.0, 0.0)
        arr = np.fromiter(self._step_ms, dtype=np.float64)
        return float(np.median(arr)), float(np.percentile(arr, 99))

    def walls(self) -> tuple[IntArray, FloatArray]:
        """The confirmed walls now: stable ids ``(W,)`` and end points ``(W, 4)`` in metres. O(walls), unlike
        :meth:`snapshot`, which also copies the whole trajectory (the robot agent calls this every step)."""
        return self._map.ids, self._map.segments()

    def recent_centroids(self, limit: int) -> FloatArray:
        """The last ``limit`` cluster centroids ``(C, 2)`` (metres, world frame), oldest first. O(limit)."""
        out: list[FloatArray] = []
        count = 0
        for block in reversed(self._centroids):
            if count >= limit:
                break
            out.append(block)
            count += len(block)
        if not out:
            return np.zeros((0, 2))
        return np.vstack(out[::-1])[-limit:]

    def map_state(self) -> MapState:
        """A copy of what the shown map holds (walls with their evidence, free space, centroids, trajectory)
        to start another pipeline from (:meth:`seed_map`); pending offline batches are not in it (flush
        first). O(map + trajectory)."""
        parts = copy.deepcopy((self._map, self._freespace, self._seen_free))
        return MapState(parts, tuple(self._centroids), tuple(self._trajectory), self._next_group)

    def seed_map(self, state: MapState) -> None:
        """Start this pipeline's shown map from ``state`` (a copy is taken): what it maps next merges into
        those walls. Only before the first step (:class:`LinemapError` otherwise)."""
        if self._version or self._trajectory:
            raise LinemapError("a pipeline's map can be seeded only before its first step")
        self._map, self._freespace, self._seen_free = copy.deepcopy(state.parts)
        self._centroids = list(state.centroids)
        self._trajectory = list(state.trajectory)
        self._next_group = state.next_group

    def continue_map(
        self, ids: IntArray, segments: FloatArray, pose: Pose2D, odometry: Pose2D | None = None
    ) -> None:
        """Go on with a map made elsewhere (the server's copy of this robot's map, on a new Robot DB): its
        walls (``ids``, ``(W, 4)`` ``segments``, m) become this pipeline's shown map, with their ids (new
        walls get larger ones), and the robot is at ``pose`` (world frame), where odometry read
        ``odometry`` (None: not known; the first scan is then taken where ``pose`` is). The first step
        predicts from there by odometry's increment and refines against those walls (the tracker's
        local maps start from them, and it has no keyframe yet), so a robot a little off the pose given
        is put back on the map. What the walls' evidence was is not known: each starts as a wall just
        confirmed (:meth:`WallMap.seed`). Only before the first step (:class:`LinemapError` otherwise,
        or for walls :meth:`WallMap.seed` refuses). O(W)."""
        if self._version or self._trajectory:
            raise LinemapError("a pipeline can continue a map only before its first step")
        try:
            self._map.seed(ids, segments)
            self._tracker.seed_local(np.asarray(segments, dtype=np.float64).reshape(-1, 4))
        except ValueError as exc:
            raise LinemapError(f"the map to continue cannot be taken: {exc}") from exc
        self._tracker.hold(pose, odometry)

    def state(self) -> MapperState:
        """The learned state as data, to restore a pipeline from (:mod:`shared.pipeline.pipestate`)."""
        from shared.pipeline.pipestate import pipeline_state

        return pipeline_state(self)

    def restore(self, state: MapperState) -> None:
        """Go on from ``state`` (:meth:`state`); before the first step only (:class:`StateError`)."""
        from shared.pipeline.pipestate import restore_pipeline

        restore_pipeline(self, state)

    def snapshot(self) -> MapSnapshot:
        """The temporary map now: walls, centroids, pose, trajectory, version. O(map + trajectory)."""
        segments = self._map.segments()
        ids = self._map.ids
        cents = np.vstack(self._centroids) if self._centroids else np.zeros((0, 2))
        traj = np.asarray(self._trajectory, dtype=np.float64).reshape(-1, 4)
        for arr in (segments, ids, cents, traj):
            arr.setflags(write=False)
        return MapSnapshot(self._version, self._stamp, segments, ids, cents, self.pose, traj)
