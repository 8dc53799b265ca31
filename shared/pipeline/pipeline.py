"""The step loop (SPEC §2-§4): one ``step(scan)`` at a time, from a scan and odometry to the line map.

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
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from shared.errors import LinemapError
from shared.kernels import REGISTRY, Stage
from shared.pipeline.censoring import censored_returns
from shared.pipeline.config import SCHEDULED, Mode, PipelineConfig
from shared.pipeline.freespace import FreeSpace
from shared.pipeline.fusion import (
    Reference,
    fuse_gated,
    hold_unseen_directions,
    prepare_reference,
    wheel_prior,
)
from shared.pipeline.gate import IcpGate
from shared.pipeline.localize import refine_to_walls
from shared.pipeline.odonoise import OdometryNoise
from shared.pipeline.rangenoise import NO_RANGE_NOISE, RangeNoise, range_noise_for
from shared.pipeline.regroup import regroup
from shared.pipeline.rematch import rematch
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
from shared.pipeline.wallmap import MergeTolerances, WallMap
from shared.types import FloatArray, IntArray, Pose2D, Scan, wrap_angle

__all__ = ["IcpGate", "MapState", "Pipeline", "StepResult"]

log = logging.getLogger(__name__)


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
    """Maps scans one step at a time. ``snapshot()`` gives the temporary map after any step."""

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
    ) -> None:
        self._config = config or PipelineConfig()
        # poses only: no shown map (a pose graph draws it later from its corrected poses, shared.slam)
        self.track_only = track_only
        # typed Any: each stage's kernels are driven through that stage's own apply signature
        self._kernels: dict[Stage, list[Any]] = dict(self._config.build())
        self._offset = laser_offset or Pose2D()
        self._gate = icp_gate or IcpGate()
        # the scanner's range noise (None: read from each scan's range window, shared.pipeline.rangenoise)
        self._range_noise = range_noise
        self._noise = range_noise or NO_RANGE_NOISE
        self.odometry_noise = OdometryNoise()  # learned from the believed matches (shared.pipeline.odonoise)
        self._map = WallMap(merge)
        self._freespace = FreeSpace()  # walls later seen through leave the map
        self._seen_free = SeenFree()  # points where earlier beams passed through stay out of the shown map
        # Localisation keeps its own local line map, built every step whatever the schedule (offline
        # batches would leave the pose uncorrected for N_smax steps); the configured stages make the map
        # shown. It is local: two maps restart in turn every `local_map_steps` steps or `local_map_m`
        # metres of travel, and the older one is matched against, so old, drifted walls of a loop never
        # pull the pose.
        self._merge = replace(
            merge or MergeTolerances(), short_by_band=False, merge_sigmas=0.0, cross_margin_m=0.0
        )
        self._loc_maps = [WallMap(self._merge), WallMap(self._merge)]
        self.local_map_restarts = 0
        self._since_steps = 0
        self._since_m = 0.0
        self._loc_lines: Any = REGISTRY.create(Stage.STRAIGHT_LINE, "hough-cluster", {"min_points": 8})
        self._centroids: list[FloatArray] = []
        self._trajectory: list[tuple[float, float, float, float]] = []
        self._pose: Pose2D | None = None
        self._prev_odom: Pose2D | None = None
        self._last_motion = Pose2D()  # the last step's estimated robot motion (constant-velocity seed)
        self._last_icp = False  # whether that motion came from a believed match
        self._key_pose: Pose2D | None = None  # robot pose of the keyframe
        self._key_points: FloatArray | None = None  # keyframe scan points, scanner frame
        self._key_odom: Pose2D | None = None  # odometry at the keyframe
        self._key_ref: Reference | None = None  # its lines and grid for the fusion, built when first needed
        self._points: FloatArray = np.zeros((0, 2))  # the last scan's returns the pose took (scanner frame)
        self._next_group = 0
        self._version = 0
        self._stamp = 0.0
        self._buffers: dict[Stage, _Buffer] = {s: _Buffer() for s in SCHEDULED}
        self._step_ms: deque[float] = deque(maxlen=timing_window)
        self._by_k: dict[int, Any] = {}
        self.icp_rejections = 0
        self.map_refinements = 0
        self.rematches = 0

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
        if pose is None:
            icp_used = self._estimate_pose(odom, points, noise)
        else:
            self._pose, self._prev_odom, icp_used = pose, odom, False
        assert self._pose is not None
        laser = self._pose @ self._offset
        world = laser.transform_points(points) if len(points) else np.zeros((0, 2))
        groups = np.where(labels >= 0, labels + self._next_group, -1).astype(np.intp)
        self._next_group += seg.n_segments
        if self._gate.refine_to_map and len(world) and pose is None:
            segments = self._loc_lines.apply(world, groups).segments
            for local in self._loc_maps:
                local.add_segments(segments)
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
        self._trajectory.append((scan.stamp_s, self._pose.x_m, self._pose.y_m, self._pose.theta_rad))
        ran: tuple[Stage, ...] = ()
        if not self.track_only:
            ran = self._feed(Chunk.of(world, groups, (laser.x_m, laser.y_m), spacing), final=False)
        self._version += 1
        elapsed = (time.perf_counter() - t0) * 1e3
        self._step_ms.append(elapsed)
        return StepResult(self._version, self._pose, icp_used, ran, elapsed)

    def flush(self) -> tuple[Stage, ...]:
        """Run every pending batch now (end of a log, or before a mode change)."""
        ran = self._feed(None, final=True)
        if ran:
            self._version += 1
        return ran

    def _estimate_pose(self, odom: Pose2D | None, points: FloatArray, range_noise: RangeNoise) -> bool:
        """Predict the pose from odometry, correct it by ICP against the keyframe scan (with a second chance
        when the gate refuses the match, :mod:`shared.pipeline.rematch`), then refine it against the local
        wall map."""
        if self._pose is None:
            self._pose = odom or Pose2D()
            self._prev_odom = odom
            self._key_pose, self._key_points, self._key_odom = self._pose, points, odom
            self._key_ref = None
            return False
        delta = Pose2D()
        if odom is not None and self._prev_odom is not None:
            delta = self._prev_odom.between(odom)
        predicted = self._pose @ delta
        self._prev_odom = odom
        icp_used = False
        plain = odom is not None  # odometry not found wrong this step (no second-chance match)
        matchers = self._kernels[Stage.SCAN_MATCHING]
        key_pose, key_points = self._key_pose, self._key_points
        if (
            matchers
            and key_pose is not None
            and key_points is not None
            and min(len(points), len(key_points)) >= 3
        ):
            # laser motion from the keyframe's scanner frame to the current one
            guess = self._to_laser(key_pose, predicted)
            match = matchers[0].apply(key_points, points, guess)
            corr = guess.between(match.pose)
            g = self._gate
            trusted = match.inlier_ratio >= g.min_inlier_ratio and self._plausible(corr, delta)
            if not trusted and g.strong_inlier_ratio <= 1.0:
                # a large correction is believed when the match itself is excellent (a fast turn)
                trusted = (
                    match.converged
                    and match.inlier_ratio >= g.strong_inlier_ratio
                    and match.rmse_m <= g.strong_rmse_m
                    and math.hypot(corr.x_m, corr.y_m) <= g.strong_max_m
                    and abs(corr.theta_rad) <= g.strong_max_rad
                )
            second = None
            if not trusted and g.rematch:
                steady = self._last_icp and g.constant_velocity
                starts = [self._to_laser(key_pose, self._pose @ self._last_motion)] if steady else []
                second = rematch(matchers[0], key_points, points, guess, match, g, starts)
                if second is not None:
                    match, trusted, plain = second, True, False
                    self.rematches += 1
            if trusted and odom is not None and self._key_odom is not None:  # odometry where scans are blind
                # a second-chance match too: odometry was found wrong where the scan fixes the motion,
                # but along a corridor's axis the search's best pose is one of many equally good ones
                # and odometry still knows better (shared.pipeline.fusion.hold_unseen_directions)
                motion = self._offset.inverse() @ self._key_odom.between(odom) @ self._offset
                if self._key_ref is None and g.fuse_odometry:
                    self._key_ref = prepare_reference(key_points, range_noise=range_noise)
                ref = self._key_ref if self._key_ref is not None else key_points
                if second is None:
                    fused = fuse_gated(g, ref, points, match.pose, motion, self.odometry_noise, range_noise)
                else:
                    fused = hold_unseen_directions(
                        g, ref, points, match.pose, motion, self.odometry_noise, range_noise
                    )
                match = replace(match, pose=fused)
            if trusted:
                predicted = key_pose @ self._offset @ match.pose @ self._offset.inverse()
                icp_used = True
            else:
                self.icp_rejections += 1
        local = self._local_map(math.hypot(delta.x_m, delta.y_m))
        if self._gate.refine_to_map and len(local):
            g = self._gate
            near = points[np.einsum("ij,ij->i", points, points) <= g.refine_range_m**2]
            scanner = predicted @ self._offset
            prior, info = (
                wheel_prior(g, self._pose @ delta @ self._offset, delta, self.odometry_noise)
                if plain
                else (None, None)
            )
            # the refinement weighs every return alike: with the range noise's weights here too (as the
            # fusion has them) the along-track error of a 5 m corridor rose from 2.1 to 7.4 cm, the end
            # walls then counting for less than the side walls' slide
            # walls of the local map whose place later beams saw through are the tracks of things that
            # moved (a person walking across in front: the local map takes every scan's lines). Not for
            # scanners without a range-noise model (the benchmark logs' SICK scanners): there the filter
            # raised Freiburg 079's relation error from 0.047 to 0.066 m and MIT's from 0.085 to 0.092
            walls = local.segments()
            if range_noise.near_m > 0.0:
                walls = walls[self._seen_free.free_share(walls) < 0.5]
            fit = refine_to_walls(
                near,
                scanner,
                walls,
                degeneracy_ratio=g.refine_degeneracy,
                prior=prior,
                prior_information=info,
            )
            if fit is not None and fit.matched >= g.refine_min_share * len(near):
                corr = scanner.between(fit.pose)
                if self._plausible(corr, delta):
                    predicted = fit.pose @ self._offset.inverse()
                    self.map_refinements += 1
        self._last_motion = self._pose.between(predicted)
        self._last_icp = icp_used
        self._pose = predicted
        moved = self._key_pose.between(predicted) if self._key_pose is not None else Pose2D()
        if (
            not icp_used
            or math.hypot(moved.x_m, moved.y_m) > self._gate.keyframe_m
            or abs(moved.theta_rad) > self._gate.keyframe_rad
        ):
            self._key_pose, self._key_points, self._key_odom = predicted, points, odom
            self._key_ref = None
        return icp_used

    def _local_map(self, travel_m: float) -> WallMap:
        """Count a step of ``travel_m`` (odometry), restart the older local map when its span is over, and
        return the one to match against (the one not restarted last)."""
        if self._since_steps >= max(self._gate.local_map_steps, 1) or self._since_m >= self._gate.local_map_m:
            self.local_map_restarts += 1
            self._loc_maps[self.local_map_restarts % 2] = WallMap(self._merge)
            self._since_steps, self._since_m = 0, 0.0
        self._since_steps += 1
        self._since_m += travel_m
        return self._loc_maps[(self.local_map_restarts + 1) % 2]

    def _to_laser(self, key_pose: Pose2D, robot: Pose2D) -> Pose2D:
        """The scanner's motion from the keyframe's scanner frame to that of the robot pose ``robot``."""
        return self._offset.inverse() @ key_pose.between(robot) @ self._offset

    def _plausible(self, corr: Pose2D, motion: Pose2D) -> bool:
        """Whether a correction of the odometry prediction is small enough to believe: within the fixed
        gate plus ``correction_ratio`` of the step's own odometry motion (wheels slip most when turning)."""
        g = self._gate
        return math.hypot(corr.x_m, corr.y_m) <= g.max_correction_m + g.correction_ratio * math.hypot(
            motion.x_m, motion.y_m
        ) and abs(corr.theta_rad) <= g.max_correction_rad + g.correction_ratio * abs(motion.theta_rad)

    # ------------------------------------------------------------------ scheduled stages
    def _ready(self, stage: Stage, buf: _Buffer, final: bool) -> bool:
        if not buf.chunks:
            return False
        sched = self._config.stage_schedule(stage)
        if final or sched.mode == Mode.ONLINE:
            return True
        if buf.steps >= sched.n_smax:
            return True
        assert self._pose is not None
        turned = abs(wrap_angle(self._pose.theta_rad - (buf.heading0 or 0.0)))
        return turned > math.radians(self._config.heading_flush_deg)

    def _feed(self, chunk: Chunk | None, final: bool) -> tuple[Stage, ...]:
        """Push a step's chunk through the scheduled stages, running each one whose batch is ready."""
        ran: list[Stage] = []
        for stage in SCHEDULED:
            buf = self._buffers[stage]
            if chunk is not None:
                if not buf.chunks:
                    buf.heading0 = self._pose.theta_rad if self._pose is not None else 0.0
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
                return out
            segments, seg_groups = extract_lines_grouped(kernels[0], batch)
            sigmas, direction_sds = line_uncertainty(segments, seg_groups, batch)
            # a noisy piece that a wall of the map explains within the range noise (tilted past the
            # merge's angle test, but not past three standard deviations of its own direction) may join
            # a wall but not start one: such pieces started the short walls crossing the demo's at
            # 10-35 degrees (issue 19 item 4, "hatching")
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
        return self._pose or Pose2D()

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

    def snapshot(self) -> MapSnapshot:
        """The temporary map now: walls, centroids, pose, trajectory, version. O(map + trajectory)."""
        segments = self._map.segments()
        ids = self._map.ids
        cents = np.vstack(self._centroids) if self._centroids else np.zeros((0, 2))
        traj = np.asarray(self._trajectory, dtype=np.float64).reshape(-1, 4)
        for arr in (segments, ids, cents, traj):
            arr.setflags(write=False)
        return MapSnapshot(self._version, self._stamp, segments, ids, cents, self.pose, traj)
