"""The front end's pose tracking: odometry prediction (paper §2, eq. 9-11), a scan match against a recent
keyframe scan (§6.2.2) believed when :class:`~shared.pipeline.gate.IcpGate` says so (with a second chance,
:mod:`shared.pipeline.rematch`, and fused with odometry by their information, :mod:`shared.pipeline.fusion`),
then a refinement against a local wall map (:mod:`shared.pipeline.localize`).

The local wall maps are the tracker's own, built every step whatever the schedule (offline batches would
leave the pose uncorrected for N_smax steps); two restart in turn every ``local_map_steps`` steps or
``local_map_m`` metres of travel and the older one is matched against, so old, drifted walls of a loop
never pull the pose. Stateful (it is the robot's sense of where it is); the kernels it calls are pure.
Cost per step: one scan match (and a second chance when refused) plus the refinement, O(N log N) for N
returns.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from shared.kernels import REGISTRY, Stage
from shared.pipeline.fusion import fuse_gated, hold_unseen_directions, wheel_prior
from shared.pipeline.fusion_solve import Reference, prepare_reference
from shared.pipeline.gate import IcpGate
from shared.pipeline.localize import refine_to_walls
from shared.pipeline.odonoise import OdometryNoise
from shared.pipeline.rangenoise import RangeNoise
from shared.pipeline.rematch import rematch
from shared.pipeline.seenfree import SeenFree
from shared.pipeline.wallmap import MergeTolerances, WallMap
from shared.types import FloatArray, IntArray, Pose2D

__all__ = ["PoseTracker"]


class PoseTracker:
    """Where the robot is, step after step. ``offset``: the scanner's pose in the robot frame; ``gate``: when
    a scan match is believed; ``merge``: the wall map's tolerances (the local maps merge without the shown
    map's noise-aware tests). ``pose`` is None before the first step."""

    def __init__(self, offset: Pose2D, gate: IcpGate, merge: MergeTolerances | None = None) -> None:
        self.offset, self.gate = offset, gate
        self.odometry_noise = OdometryNoise()  # learned from the believed matches (shared.pipeline.odonoise)
        self._merge = replace(
            merge or MergeTolerances(), short_by_band=False, merge_sigmas=0.0, cross_margin_m=0.0
        )
        self._loc_maps = [WallMap(self._merge), WallMap(self._merge)]
        self.local_map_restarts = 0
        self._since_steps = 0
        self._since_m = 0.0
        self._loc_lines: Any = REGISTRY.create(Stage.STRAIGHT_LINE, "hough-cluster", {"min_points": 8})
        self.pose: Pose2D | None = None
        self._prev_odom: Pose2D | None = None
        self._last_motion = Pose2D()  # the last step's estimated robot motion (constant-velocity seed)
        self._last_icp = False  # whether that motion came from a believed match
        self._key_pose: Pose2D | None = None  # robot pose of the keyframe
        self._key_points: FloatArray | None = None  # keyframe scan points, scanner frame
        self._key_odom: Pose2D | None = None  # odometry at the keyframe
        self._key_ref: Reference | None = None  # its lines and grid for the fusion, built when first needed
        self.icp_rejections = 0
        self.map_refinements = 0
        self.rematches = 0

    def hold(self, pose: Pose2D, odom: Pose2D | None) -> None:
        """Take ``pose`` as the robot's pose (a known pose, as a pose graph's corrected trajectory gives);
        the local maps are left alone."""
        self.pose, self._prev_odom = pose, odom

    def seed_local(self, segments: FloatArray) -> None:
        """Start both local wall maps from ``segments`` (``(W, 4)``, world frame, m: a continued map's
        walls), so that the first steps refine the pose against the map being continued (an empty
        tracker only: before the first step). O(W)."""
        for local in self._loc_maps:
            local.seed(np.arange(len(segments)), segments)

    def add_lines(self, world: FloatArray, groups: IntArray) -> None:
        """Add a step's returns (world frame, with their segment ids) to the local wall maps, as lines."""
        if self.gate.refine_to_map and len(world):
            segments = self._loc_lines.apply(world, groups).segments
            for local in self._loc_maps:
                local.add_segments(segments)

    def estimate(
        self,
        odom: Pose2D | None,
        points: FloatArray,
        range_noise: RangeNoise,
        matchers: list[Any],
        seen_free: SeenFree,
    ) -> bool:
        """Predict the pose from odometry, correct it by ICP against the keyframe scan (with a second chance
        when the gate refuses the match, :mod:`shared.pipeline.rematch`), then refine it against the local
        wall map. ``matchers``: the scan-matching kernel in force (empty: odometry alone); ``seen_free``:
        where earlier beams passed through (walls of the local map there are left out). Returns whether a
        scan match was believed."""
        if self.pose is None:
            self.pose = odom or Pose2D()
            self._prev_odom = odom
            self._key_pose, self._key_points, self._key_odom = self.pose, points, odom
            self._key_ref = None
            return False
        delta = Pose2D()
        if odom is not None and self._prev_odom is not None:
            delta = self._prev_odom.between(odom)
        predicted = self.pose @ delta
        self._prev_odom = odom
        icp_used = False
        plain = odom is not None  # odometry not found wrong this step (no second-chance match)
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
            g = self.gate
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
                starts = [self._to_laser(key_pose, self.pose @ self._last_motion)] if steady else []
                second = rematch(matchers[0], key_points, points, guess, match, g, starts)
                if second is not None:
                    match, trusted, plain = second, True, False
                    self.rematches += 1
            if trusted and odom is not None and self._key_odom is not None:  # odometry where scans are blind
                # a second-chance match too: odometry was found wrong where the scan fixes the motion,
                # but along a corridor's axis the search's best pose is one of many equally good ones
                # and odometry still knows better (shared.pipeline.fusion.hold_unseen_directions)
                motion = self.offset.inverse() @ self._key_odom.between(odom) @ self.offset
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
                predicted = key_pose @ self.offset @ match.pose @ self.offset.inverse()
                icp_used = True
            else:
                self.icp_rejections += 1
        local = self._local_map(math.hypot(delta.x_m, delta.y_m))
        if self.gate.refine_to_map and len(local):
            g = self.gate
            near = points[np.einsum("ij,ij->i", points, points) <= g.refine_range_m**2]
            scanner = predicted @ self.offset
            prior, info = (
                wheel_prior(g, self.pose @ delta @ self.offset, delta, self.odometry_noise)
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
                walls = walls[seen_free.free_share(walls) < 0.5]
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
                    predicted = fit.pose @ self.offset.inverse()
                    self.map_refinements += 1
        self._last_motion = self.pose.between(predicted)
        self._last_icp = icp_used
        self.pose = predicted
        moved = self._key_pose.between(predicted) if self._key_pose is not None else Pose2D()
        if (
            not icp_used
            or math.hypot(moved.x_m, moved.y_m) > self.gate.keyframe_m
            or abs(moved.theta_rad) > self.gate.keyframe_rad
        ):
            self._key_pose, self._key_points, self._key_odom = predicted, points, odom
            self._key_ref = None
        return icp_used

    def _local_map(self, travel_m: float) -> WallMap:
        """Count a step of ``travel_m`` (odometry), restart the older local map when its span is over, and
        return the one to match against (the one not restarted last)."""
        if self._since_steps >= max(self.gate.local_map_steps, 1) or self._since_m >= self.gate.local_map_m:
            self.local_map_restarts += 1
            self._loc_maps[self.local_map_restarts % 2] = WallMap(self._merge)
            self._since_steps, self._since_m = 0, 0.0
        self._since_steps += 1
        self._since_m += travel_m
        return self._loc_maps[(self.local_map_restarts + 1) % 2]

    def _to_laser(self, key_pose: Pose2D, robot: Pose2D) -> Pose2D:
        """The scanner's motion from the keyframe's scanner frame to that of the robot pose ``robot``."""
        return self.offset.inverse() @ key_pose.between(robot) @ self.offset

    def _plausible(self, corr: Pose2D, motion: Pose2D) -> bool:
        """Whether a correction of the odometry prediction is small enough to believe: within the fixed
        gate plus ``correction_ratio`` of the step's own odometry motion (wheels slip most when turning)."""
        g = self.gate
        return math.hypot(corr.x_m, corr.y_m) <= g.max_correction_m + g.correction_ratio * math.hypot(
            motion.x_m, motion.y_m
        ) and abs(corr.theta_rad) <= g.max_correction_rad + g.correction_ratio * abs(motion.theta_rad)
