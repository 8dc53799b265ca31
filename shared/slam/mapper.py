"""Mapping with loop closure: the front end's poses under a keyframe pose graph, the map rebuilt from the
corrected poses.

:class:`GraphMapper` drives a :class:`~shared.pipeline.Pipeline` (the front end: scan matching fused with
odometry, the local wall refinement) one scan at a time and keeps, beside it,

- **keyframes**: every ``keyframe_m`` of travel or ``keyframe_rad`` of turn, the front end's pose and the
  scan's returns (robot frame) that the pose estimate took;
- **sequential edges** between consecutive keyframes: the front end's relative pose, with the point-to-line
  information of the two keyframes' scans (:func:`shared.slam.information.scan_edge`, the front end's own
  model: across walls, not along a featureless corridor) plus odometry's (its noise model scaled by the
  factors the front end learned), and a covariance floor for what a match misses
  (:func:`shared.slam.edges.with_floor`: 2 mm + 0.5 % of the travel, 0.02 degrees + 0.03 degrees per metre
  + 0.5 % of the turn);
- **skip edges** from 4, 8 and 16 keyframes back where the scans overlap (the front end matches against a
  local wall map, so its error over metres is far below a random walk of its keyframe errors);
- **loop-closure edges** (:mod:`shared.slam.closure`): verified matches of the current keyframe against
  an earlier place, robust in the graph (:mod:`shared.slam.graph`); once a closure tied the robot's
  stretch to a place, the searches there are as wide as the graph's uncertainty of the relative pose
  allows (:mod:`shared.slam.window`).

The corrected pose of step ``s`` is ``G(k) F(k)^-1 F(s)`` for the last keyframe ``k`` at or before it
(``F`` the front end's pose, ``G`` the graph's): the front end runs undisturbed in its own frame, and the
graph moves its keyframes. The map is a function of the graph: :meth:`GraphMapper.finish` optimises the
whole graph once more (``final_batch``) and maps every scan again at its corrected pose with a fresh
pipeline (:meth:`shared.pipeline.Pipeline.step` with ``pose``), so walls drawn twice before a loop was
closed come out once.

Memory: every keyframe's returns (twice: robot and scanner frame) and every scan for the rebuild (8 bytes
a beam): about 12 MB for ACES' 7,374 scans; with ``redraw_spacing`` (the robot's online mapper) only the
scans that far apart are kept for redraws, and with ``places`` a building driven again holds one keyframe
scan and three kept scans per place (:mod:`shared.slam.places`).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from shared.kernels import REGISTRY, Stage
from shared.pipeline import MapSnapshot, Pipeline
from shared.pipeline.fusion_solve import mahalanobis2, odometry_information
from shared.pipeline.pipeline import StepResult
from shared.protocol.trajectory import thin_positions
from shared.slam.chainsum import ChainSums
from shared.slam.closure import MIN_PAIRS, LoopMatch, candidates, stacked, verify
from shared.slam.edges import AGREEMENT_CHI2, consistent, hold_unseen, with_floor
from shared.slam.errors import OptimisationError
from shared.slam.frontproc import Tracked
from shared.slam.graph import PoseGraph
from shared.slam.information import match_information, scan_edge
from shared.slam.places import SCAN_PLACE, SCANS_PER_PLACE, TIED_KEYFRAMES, Places, superseded
from shared.slam.rows import Rows
from shared.slam.settings import LoopClosureSettings
from shared.slam.window import search_window
from shared.types import BoolArray, FloatArray, IntArray, Pose2D, Scan

__all__ = ["GraphMapper", "Keyframe", "LoopClosure"]

log = logging.getLogger(__name__)

#: skip edges (GraphMapper._add_skip_edges): from these many keyframes back, within SKIP_MAX_M of travel
SKIP_KEYFRAMES = (4, 8, 16)
SKIP_MAX_M = 10.0


@dataclass(frozen=True, slots=True)
class Keyframe:
    """A keyframe: its step, the front end's robot pose then, odometry then, the returns (robot frame and
    scanner frame in beam order, m), the distance travelled up to it (m, by the front end's poses) and
    its scan's time stamp (s)."""

    step: int
    frontend: Pose2D
    odometry: Pose2D | None
    points: FloatArray
    scan: FloatArray
    travelled_m: float
    stamp_s: float


@dataclass(frozen=True, slots=True)
class LoopClosure:
    """An accepted loop closure: keyframe ``current`` seen in keyframe ``candidate``'s frame at ``pose``."""

    current: int
    candidate: int
    pose: Pose2D
    inlier_share: float


class GraphMapper:
    """The front end under a pose graph (module docstring). ``make_pipeline`` builds a pipeline (called
    once for the front end and once for the final map)."""

    def __init__(
        self,
        make_pipeline: Callable[[], Pipeline],
        settings: LoopClosureSettings | None = None,
        *,
        front: Pipeline | None = None,
        redraw_spacing: tuple[float, float] | None = None,
        history: int | None = None,
        places: bool = False,
    ) -> None:
        self._make = make_pipeline
        self.settings = settings or LoopClosureSettings()
        # the front end: a new pipeline, or one that has mapped already (the graph starts at its pose)
        self.front = front if front is not None else make_pipeline()
        self.graph = PoseGraph(robust_sigmas=self.settings.robust_sigmas)
        self._matcher = REGISTRY.create(
            Stage.SCAN_MATCHING, "icp", {"max_correspondence_m": 0.3, "refine_correspondence_m": 0.1}
        )
        self.keyframes: list[Keyframe] = []
        self.closures: list[LoopClosure] = []
        # what the state keeps of the records above (and of the kept scans below) as rows, so a state is
        # taken in array copies, not an object per keyframe, closure and kept scan (shared.slam.onlinestate):
        # per keyframe its odometry (x, y, theta; NaN: none), per closure its pose and inlier share, per kept
        # scan its step and odometry
        self._odometry = Rows(3)
        self._closure_rows = Rows(4)
        self._scan_rows = Rows(4)
        self._pairs = Rows(2)  # per closure: its current and candidate keyframe (counted vectorised)
        self._pair_cov = Rows(9)  # per closure: its covariance (row-major; the search windows it allows)
        self.candidates_tried = 0
        self.optimise_ms: list[float] = []
        # per step: stamp, the front end's pose (x, y, theta), its keyframe; ``history`` poses at most
        # (thinned as the pipeline's trajectory is, shared.protocol.trajectory.thin_positions)
        self._track = Rows(5)
        self._history = history
        self._n_steps = 0
        self._travelled = 0.0
        self._last: Pose2D | None = None
        # the scans a redraw maps again: every one, or (``redraw_spacing`` = (m, rad)) one each time the
        # robot moved or turned that much since the last one kept, with its step index
        self._scans: list[tuple[int, Scan | None, Pose2D | None]] = []
        self._kept = Rows(4)  # per kept scan: the front end's pose (x, y, theta) and its keyframe
        # per keyframe: the front end's pose (x, y, theta), the travel up to it (m), its scan's stamp (s) and
        # its step
        self._fronts = Rows(6)
        #: which keyframes and kept scans a building driven again holds (shared.slam.places; the robot's)
        self.places = Places(places)
        self._spacing = redraw_spacing
        self._kept_at: Pose2D | None = None
        self._seq_cov = Rows(9)  # covariance of the sequential edge k -> k + 1 (row-major)
        #: search for loop closures in the step (offline); the online mapper searches on a worker instead
        self.search_inline = True
        self.adopt_front()

    # ------------------------------------------------------------------ stepping
    def step(
        self, scan: Scan, odometry: Pose2D | None = None, *, tracked: Tracked | None = None
    ) -> StepResult:
        """One scan through the front end, then the graph; the result's pose is the corrected one.
        ``tracked``: what a front end elsewhere made of this scan (:mod:`shared.slam.frontproc`); the
        front end here is then not stepped."""
        if tracked is None:
            tracked = Tracked.of(self.front, self.front.step(scan, odometry))
        self._now = tracked
        result = tracked.result
        odom = odometry if odometry is not None else scan.odometry
        pose = result.pose
        step = self._n_steps
        if self._last is not None:
            self._travelled += math.hypot(*self._last.between(pose).as_tuple()[:2])
        self._last = pose
        if self._is_keyframe(pose):
            self._add_keyframe(step, pose, odom, scan.stamp_s)
        key = len(self.keyframes) - 1
        if self._keep(pose):
            self._scans.append((step, scan, odometry))
            self._scan_rows.append((step, *_pose_row(odometry)))
            self._kept.append((pose.x_m, pose.y_m, pose.theta_rad, key))
            self.places.add_scan()
        self._track.append((scan.stamp_s, pose.x_m, pose.y_m, pose.theta_rad, key))
        self._n_steps += 1
        if self._history is not None and len(self._track) > self._history:
            self._track.drop(thin_positions(len(self._track), self._history))
        return replace(result, pose=self.pose)

    def adopt_front(self) -> None:
        """Read what the graph takes from the front end (its last scan's returns, the noise it learned,
        the range noise) off ``self.front`` as it is now: at the start, and after a restore gave it a
        front end. O(1)."""
        self._now = Tracked.of(self.front, StepResult(self.front.version, self.front.pose, False, (), 0.0))

    def _keep(self, pose: Pose2D) -> bool:
        """Whether the scan at front-end pose ``pose`` is kept for redraws (``redraw_spacing``)."""
        if self._spacing is None:
            return True
        if self._kept_at is not None:
            moved = self._kept_at.between(pose)
            far, turn = self._spacing
            if math.hypot(moved.x_m, moved.y_m) < far and abs(moved.theta_rad) < turn:
                return False
        self._kept_at = pose
        return True

    def _is_keyframe(self, pose: Pose2D) -> bool:
        if not self.keyframes:
            return True
        moved = self.keyframes[-1].frontend.between(pose)
        s = self.settings
        return math.hypot(moved.x_m, moved.y_m) >= s.keyframe_m or abs(moved.theta_rad) >= s.keyframe_rad

    def _add_keyframe(self, step: int, pose: Pose2D, odom: Pose2D | None, stamp_s: float) -> None:
        offset = self.front.laser_offset
        scan = self._now.scan_points
        points = offset.transform_points(scan) if len(scan) else np.zeros((0, 2))
        key = Keyframe(step, pose, odom, points, scan, self._travelled, stamp_s)
        self._fronts.append((pose.x_m, pose.y_m, pose.theta_rad, self._travelled, stamp_s, step))
        self._odometry.append(_pose_row(odom))
        self.places.add_keyframe()
        if not self.keyframes:
            self.keyframes.append(key)
            self.graph.add_node(pose)
            self.graph.update()
            return
        prev = self.keyframes[-1]
        k_prev = len(self.keyframes) - 1
        motion = prev.frontend.between(pose)
        guess = self.graph.pose(k_prev) @ motion
        self.keyframes.append(key)
        k = self.graph.add_node(guess)
        seq_info = self._sequential_information(prev, key, motion)
        self.graph.add_edge(k_prev, k, motion, seq_info, loop=False)
        self._seq_cov.append(np.linalg.inv(seq_info).ravel().tolist())
        self._add_skip_edges(k)
        if self.settings.enabled and self.search_inline:
            self.add_closures(k, self.find_closures(k))
            self.retire_places(k)
            self.free_retired(self.places.keyframes_retired, self.places.scans_retired)  # no job pending
        else:
            self._update()

    def find_closures(
        self,
        k: int,
        poses: FloatArray | None = None,
        held_upto: int | None = None,
        closures_upto: int | None = None,
    ) -> list[LoopMatch]:
        """The verified loop closures of keyframe ``k`` (the slow part: correlative searches) with the
        graph's estimate ``poses`` (``(K, 3)`` rows of :meth:`PoseGraph.pose_array`, K > k; default: the
        current one) against the keyframes held when ``held_upto`` keyframes had been retired
        (:mod:`shared.slam.places`; default: now), each search's window narrowed by the first
        ``closures_upto`` accepted closures (:mod:`shared.slam.window`; default: all). Changes nothing and
        reads only keyframes up to ``K - 1``, so with ``poses``, ``held_upto`` and ``closures_upto`` taken
        when ``k`` was added it may run beside the step (:mod:`shared.slam.online`) and finds the same
        closures whenever it runs."""
        estimate = self.graph.pose_array() if poses is None else poses
        return self._loop_matches(k, estimate, held_upto, closures_upto)

    def add_closures(self, k: int, matches: list[LoopMatch]) -> int:
        """Turn verified ``matches`` of keyframe ``k`` into loop edges (refined, held where blind, checked
        against the graph) and update the graph; returns how many were added."""
        added = 0
        for match in matches:
            edge = self._loop_edge(match, k)
            if edge is None:
                continue
            pose, info = edge
            if not self._consistent(match.candidate, k, pose, info):
                continue
            # closures between the same two stretches of the path share their errors (the same faces
            # seen from the same sides): the n-th of them counts 1/n, not as a new witness
            self.graph.add_edge(
                match.candidate, k, pose, info / (1 + self._witnesses(k, match.candidate)), loop=True
            )
            self.closures.append(LoopClosure(k, match.candidate, pose, match.inlier_share))
            self._closure_rows.append((pose.x_m, pose.y_m, pose.theta_rad, match.inlier_share))
            self._pairs.append((k, match.candidate))
            self._pair_cov.append(np.linalg.inv(info).ravel().tolist())
            added += 1
        self._update()
        return added

    def _witnesses(self, k: int, c: int) -> int:
        """How many accepted closures join the stretch of keyframe ``k`` to that of ``c`` (within twice
        ``submap_keyframes`` of each). O(closures), vectorised."""
        near = 2 * self.settings.submap_keyframes
        pairs = self._pairs.view()
        return int(np.count_nonzero((np.abs(pairs[:, 0] - k) <= near) & (np.abs(pairs[:, 1] - c) <= near)))

    def _tie(self, j: int, anchor: int) -> bool:
        """Measure the loop edge that lets keyframe ``j``, retiring at ``anchor``'s place with no closure
        joining the two, ride on it (:mod:`shared.slam.riders` carries only a keyframe whose offset rests on
        a measurement): ``j``'s scan matched point-to-line onto ``anchor``'s own scan from the graph's
        estimate (they are at one place, ``places.near``), accepted when at least ``min_inlier_share`` of
        its returns lie within ``inlier_m`` there (and :data:`~shared.slam.closure.MIN_PAIRS` pairs), held
        along its blind directions (a corridor's length stays the graph's) and consistent with the graph,
        as a closure's refinement is (:meth:`_loop_edge`, :meth:`_consistent`); counted like a closure
        between the same two stretches (1/n). Not a :class:`LoopClosure` record: it ties a keyframe to its
        place, it is no evidence that the robot is at an earlier visit (that needs a search:
        :func:`shared.slam.closure.verify`), so it moves no search window and no retirement. Returns
        whether the edge was added. O(N log N) for N returns."""
        ref, cur = self.keyframes[anchor], self.keyframes[j]
        if len(ref.points) < MIN_PAIRS or len(cur.points) < MIN_PAIRS:
            return False
        guess = self.graph.pose(anchor).between(self.graph.pose(j))
        refined = self._scan_edge(ref, cur, guess, refine=True)
        if refined is None:
            return False
        pose, info = refined
        s = self.settings
        fit = match_information(
            ref.points, cur.points, pose, inlier_m=s.inlier_m, range_noise=self._now.range_noise
        )
        if fit.inlier_share < s.min_inlier_share or fit.pairs < MIN_PAIRS:
            return False
        info = with_floor(info, Pose2D(pose.x_m, pose.y_m, 0.0))
        pose, info = self._hold_unseen(anchor, j, pose, np.asarray(np.linalg.inv(info), dtype=np.float64))
        if not self._consistent(anchor, j, pose, info):
            return False
        self.graph.add_edge(anchor, j, pose, info / (1 + self._witnesses(j, anchor)), loop=True)
        return True

    def _update(self) -> None:
        t0 = time.perf_counter()
        try:
            self.graph.update()
        except OptimisationError as exc:
            log.warning("pose graph: %s; keeping the estimate from before", exc)
        self.optimise_ms.append((time.perf_counter() - t0) * 1e3)

    def chain_covariance(self, c: int, k: int) -> FloatArray:
        """Covariance ``(3, 3)`` of keyframe ``k`` in keyframe ``c``'s frame by the sequential edges alone
        (:func:`shared.slam.closure.chain_covariance`, from prefix sums: :mod:`shared.slam.chainsum`).
        O(1) (amortised; the sums are a cache, rebuilt from the rows after a restore)."""
        sums: ChainSums | None = self.__dict__.get("_chain_sums")
        if sums is None:
            sums = self._chain_sums = ChainSums()
        return sums.covariance(self._fronts.view()[:, :3], self._seq_cov.view(), c, k)

    def _consistent(self, c: int, k: int, pose: Pose2D, info: FloatArray) -> bool:
        """Whether a loop closure ``pose`` (keyframe ``k`` in ``c``'s frame) agrees with the graph's
        estimate of it (:func:`shared.slam.edges.consistent`, under :meth:`chain_covariance`)."""
        predicted = self.graph.pose(c).between(self.graph.pose(k))
        return consistent(predicted, pose, info, self.chain_covariance(c, k))

    def _add_skip_edges(self, k: int) -> None:
        """Edges from keyframes ``SKIP_KEYFRAMES`` back to ``k``, where their scans overlap: the front
        end's relative pose with the point-to-line information of the two scans. The front end matches
        against a local wall map spanning metres of travel, so its error over several keyframes is far
        below a random walk of its keyframe-to-keyframe errors; these edges say so, and one loop closure
        a little off cannot bend a whole lap that the front end had right."""
        key = self.keyframes[k]
        for j in SKIP_KEYFRAMES:
            if k - j < 0 or key.travelled_m - self.keyframes[k - j].travelled_m > SKIP_MAX_M:
                continue
            ref = self.keyframes[k - j]
            motion = ref.frontend.between(key.frontend)
            edge = self._scan_edge(ref, key, motion, refine=False)
            if edge is None:
                continue
            self.graph.add_edge(k - j, k, motion, with_floor(edge[1], motion), loop=False)

    def _scan_edge(
        self, ref: Keyframe, cur: Keyframe, motion: Pose2D, refine: bool
    ) -> tuple[Pose2D, FloatArray] | None:
        return scan_edge(
            ref.scan,
            cur.scan,
            motion,
            self.front.laser_offset,
            sigma_m=self.front.gate.match_sigma_m,
            range_noise=self._now.range_noise,
            refine=refine,
        )

    def _loop_edge(self, match: LoopMatch, k: int) -> tuple[Pose2D, FloatArray] | None:
        """The searched loop closure refined point-to-line against the candidate keyframe's own scan, with
        that match's information and the floor; ``None`` when the refinement finds too few pairs or the
        two estimates disagree (``AGREEMENT_CHI2``)."""
        refined = self._scan_edge(self.keyframes[match.candidate], self.keyframes[k], match.pose, refine=True)
        if refined is None:
            return None
        pose, info = refined
        info = with_floor(info, Pose2D(pose.x_m, pose.y_m, 0.0))  # a view, not a turn: no turn term
        if mahalanobis2(match.pose, pose, info) > AGREEMENT_CHI2:
            return None
        # no more certain than the score surface says: its spread adds to the translation's covariance
        cov: FloatArray = np.asarray(np.linalg.inv(info), dtype=np.float64)
        cov += match.spread
        return self._hold_unseen(match.candidate, k, pose, cov)

    def _hold_unseen(self, c: int, k: int, pose: Pose2D, cov: FloatArray) -> tuple[Pose2D, FloatArray]:
        """The closure held along its blind directions (:func:`shared.slam.edges.hold_unseen`) at the
        graph's estimate of keyframe ``k`` in ``c``'s frame. O(1)."""
        return hold_unseen(self.graph.pose(c).between(self.graph.pose(k)), pose, cov)

    def _sequential_information(self, prev: Keyframe, key: Keyframe, motion: Pose2D) -> FloatArray:
        """The front end's motion between two keyframes: scan information plus odometry's, then the floor."""
        edge = self._scan_edge(prev, key, motion, refine=False)
        info = edge[1].copy() if edge is not None else np.zeros((3, 3))
        if prev.odometry is not None and key.odometry is not None:
            g = self.front.gate
            odo_motion = prev.odometry.between(key.odometry)
            model = odometry_information(
                odo_motion,
                sigma_m=g.odom_sigma_m,
                sigma_ratio=g.odom_sigma_ratio,
                sigma_rad=g.odom_sigma_rad,
                sigma_rad_per_rad=g.odom_sigma_rad_per_rad,
            )
            k = self._now.noise_scale
            d = 1.0 / np.sqrt([k.translation, k.translation, k.heading])
            info = info + model * np.outer(d, d)
        return with_floor(info, motion)

    def _loop_matches(
        self, k: int, estimate: FloatArray, held_upto: int | None, closures_upto: int | None
    ) -> list[LoopMatch]:
        """Verified loop closures of keyframe ``k`` against its candidates among the keyframes held as of
        ``held_upto`` retirements, under ``estimate`` ``(K, 3)``, in windows the first ``closures_upto``
        closures allow."""

        def pose(i: int) -> Pose2D:  # only the few a search reads, not a Pose2D per keyframe each search
            x, y, th = estimate[i].tolist()
            return Pose2D(x, y, th)

        upto = len(self._pairs) if closures_upto is None else closures_upto
        ties, tie_covs = self._pairs.view()[:upto], self._pair_cov.view()[:upto]
        seq_cov = self._seq_cov.view()
        travelled = np.array(self._fronts.view()[: len(estimate), 3])
        held = self.places.keyframes_held(held_upto)[: len(estimate)]
        found: list[LoopMatch] = []
        for c in candidates(estimate[:, :2], travelled, k, self.settings, estimate[:, 2], held):
            self.candidates_tried += 1
            lo = max(c - self.settings.submap_keyframes, 0)
            hi = min(c + self.settings.submap_keyframes, k - 1)
            origin = pose(c)
            parts = [
                origin.between(pose(m)).transform_points(self.keyframes[m].points)
                for m in range(lo, hi + 1)
                if held[m]
                and len(self.keyframes[m].points)
                and self.keyframes[m].travelled_m <= travelled[k] - self.settings.recent_m
            ]
            guess = origin.between(pose(k))
            match = verify(
                stacked(parts),
                self.keyframes[k].points,
                guess,
                c,
                self.settings,
                self._matcher,
                range_noise=self._now.range_noise,
                window=search_window(estimate, seq_cov, c, k, ties, tie_covs, self.settings),
            )
            if match is not None:
                found.append(match)
        return found

    # ------------------------------------------------------------------ reading
    @property
    def pose(self) -> Pose2D:
        """The corrected robot pose now (world frame)."""
        if self._last is None or not self.keyframes:
            return Pose2D()
        return self._corrected(self._last, len(self.keyframes) - 1)

    def _corrected(self, frontend: Pose2D, key: int) -> Pose2D:
        kf = self.keyframes[key]
        return self.graph.pose(key) @ kf.frontend.between(frontend)

    def kept_pose(self, i: int, estimate: FloatArray) -> Pose2D:
        """The pose of the ``i``-th scan kept for redraws (:meth:`stepped`) under the graph's estimate
        ``estimate`` (``(K, 3)`` rows, as :meth:`PoseGraph.pose_array` gave them; the scan's keyframe
        must be among them). O(1)."""
        fx, fy, fth, key = self._kept.row(i).tolist()
        x, y, th = estimate[int(key)].tolist()
        return Pose2D(x, y, th) @ self.keyframes[int(key)].frontend.between(Pose2D(fx, fy, fth))

    def keyframe_rows(self) -> list[list[float]]:
        """The keyframes as the wire has them (:mod:`shared.protocol.posegraph`): ``[keyframe_id,
        stamp_s, x_m, y_m, theta_rad]`` at the graph's current estimate. O(keyframes)."""
        rows: list[list[float]] = self.keyframe_array().tolist()
        return rows

    def keyframe_array(self, since: int = 0) -> FloatArray:
        """:meth:`keyframe_rows` from keyframe ``since`` on as one array ``(K - since, 5)``.
        O(K - since), vectorised."""
        fronts = self._fronts.view()
        estimate = self.graph.pose_array()
        n = min(len(fronts), len(estimate))
        n = int(np.searchsorted(fronts[:n, 5], self._n_steps))  # made in a step that is over
        since = min(since, n)
        out = np.empty((n - since, 5))
        out[:, 0] = np.arange(since, n)
        out[:, 1] = fronts[since:n, 4]
        out[:, 2:] = estimate[since:n]
        return out

    def closure_pairs(self, since: int = 0) -> list[list[int]]:
        """The accepted loop closures from the ``since``-th on as ``[keyframe_id, keyframe_id]`` (earlier
        place first). O(closures since)."""
        return [[c.candidate, c.current] for c in self.closures[since:]]

    def trajectory(self) -> FloatArray:
        """The corrected trajectory ``(N, 4)``: stamp (s), x, y (m), heading (rad) per step (with a
        ``history``, the steps kept: every recent one, ever sparser older ones). O(N), vectorised."""
        track = self._track.view()
        if not len(track):
            return np.zeros((0, 4))
        keys = track[:, 4].astype(np.intp)
        fronts = self._fronts.view()[:, :3]
        out = np.empty((len(track), 4))
        out[:, 0] = track[:, 0]
        out[:, 1:] = _compose(self.graph.pose_array()[keys], _between(fronts[keys], track[:, 1:4]))
        return out

    def finish(self) -> MapSnapshot:
        """Optimise the whole graph once more (``final_batch``) and map every scan again at its corrected
        pose; the snapshot's trajectory is the corrected one. O(scans x map step)."""
        if self.settings.final_batch and len(self.graph) > 1:
            t0 = time.perf_counter()
            try:
                self.graph.optimise_batch()
            except OptimisationError as exc:
                log.warning("pose graph: %s; keeping the incremental estimate", exc)
            self.optimise_ms.append((time.perf_counter() - t0) * 1e3)
        self.front.flush()
        if not self.front.track_only and (not self.settings.enabled or not self.closures):
            return self.front.snapshot()
        rebuilt = self._make()
        estimate = self.graph.pose_array()
        held = self.places.scans_held()
        for i, (_step, scan, odometry) in enumerate(self._scans):
            if scan is not None and held[i]:
                rebuilt.step(scan, odometry, pose=self.kept_pose(i, estimate))
        rebuilt.flush()
        return rebuilt.snapshot()

    def stepped(self) -> list[tuple[int, Scan | None, Pose2D | None]]:
        """The scans kept for a redraw, in order, each with its step index and the odometry it was given:
        every scan stepped, or those ``redraw_spacing`` apart; a retired one whose data was freed holds
        None (:mod:`shared.slam.places`)."""
        return self._scans

    # ------------------------------------------------------------------ places
    def retire_places(self, k: int) -> None:
        """With places on: retire each keyframe that has just fallen far enough behind keyframe ``k`` (never
        one a sequential or skip edge still reads) where an older held keyframe holds its place and a loop
        closure tied its stretch to it; it rides on that keyframe (:func:`shared.slam.places.superseded`).
        With the robot's stretch tied to an earlier visit (a closure accepted at most
        :data:`~shared.slam.places.TIED_KEYFRAMES` keyframes before ``k``), also retire the held kept scans
        at the places of keyframe ``k - 1``'s kept scans among those travelled well before. Under the
        graph's estimate now, in the step, at the join of ``k``'s loop search (:mod:`shared.slam.places`).
        O(held keyframes + held kept scans), vectorised."""
        p = self.places
        if not p.enabled or not self.closures:
            return
        s = self.settings
        estimate = self.graph.pose_array()
        fronts = self._fronts.view()
        travelled = fronts[:, 3]
        gap = max(s.recent_m, SKIP_MAX_M) + s.keyframe_m
        limit = travelled[k] - gap
        n = len(estimate)
        first = int(np.searchsorted(travelled[:n], travelled[k - 1] - gap)) if k > 0 else 0
        last = int(np.searchsorted(travelled[:n], limit))
        held = p.keyframes_held()[:n]
        place = (s.keyframe_m / 2, s.keyframe_rad)
        pairs, tied = self._pairs.view(), 0
        for j, anchor in superseded(estimate, travelled[:n], held, pairs, range(first, last), gap, place):
            joined = np.any((pairs[:, 0] == j) & (pairs[:, 1] == anchor))
            tied += int(not joined and self._tie(j, anchor))  # else it stays in the solver (riders)
            p.retire_keyframes(np.array([j]))
            self.graph.ride(j, anchor)  # out of the solver at its next rebuild, carried by the place's first
        if tied:
            self._update()
        if self.closures[-1].current < k - TIED_KEYFRAMES:
            return
        kept = self._kept.view()
        keys = kept[:, 3].astype(np.intp)
        new = np.flatnonzero(keys == k - 1)
        old_s = np.flatnonzero(p.scans_held() & (travelled[keys] < limit))
        if not len(new) or not len(old_s):
            return

        def at(i: IntArray) -> FloatArray:  # kept scans' poses under the graph now
            return _compose(estimate[keys[i]], _between(fronts[keys[i], :3], kept[i, :3]))

        # the old held scans at a new one's place, then of those the ones with SCANS_PER_PLACE held scans
        # newer than themselves at their own place (among those and the new ones)
        near_new = _at_place(at(old_s), at(new))
        cand = old_s[near_new.any(axis=1)]
        if not len(cand):
            return
        pool = np.concatenate([cand, new])
        newer = _at_place(at(cand), at(pool)) & (pool[None, :] > cand[:, None])
        p.retire_scans(cand[newer.sum(axis=1) >= SCANS_PER_PLACE])

    def free_retired(self, keyframes_upto: int, scans_upto: int) -> None:
        """Drop the data (returns) of the keyframes and kept scans retired before the ``keyframes_upto``-th
        and ``scans_upto``-th retirement: no job that may still read them (one begun before) is pending.
        O(freed)."""
        keys, scans = self.places.free_upto(keyframes_upto, scans_upto)
        for j in keys:
            self.keyframes[j] = replace(self.keyframes[j], points=_NO_POINTS, scan=_NO_POINTS)
        for i in scans:
            step, _scan, odometry = self._scans[i]
            self._scans[i] = (step, None, odometry)


_NO_POINTS = np.zeros((0, 2))
_NO_POINTS.setflags(write=False)


def _pose_row(pose: Pose2D | None) -> tuple[float, float, float]:
    """``(x, y, theta)`` of ``pose``, NaN for none."""
    return (math.nan, math.nan, math.nan) if pose is None else (pose.x_m, pose.y_m, pose.theta_rad)


def _at_place(a: FloatArray, b: FloatArray) -> BoolArray:
    """``(len(a), len(b))``: whether pose row ``a[i]`` is at ``b[j]``'s place (:data:`SCAN_PLACE`)."""
    radius, turn = SCAN_PLACE
    dist = np.hypot(a[:, None, 0] - b[None, :, 0], a[:, None, 1] - b[None, :, 1])
    out: BoolArray = (dist <= radius) & (np.abs(_wrap(a[:, None, 2] - b[None, :, 2])) <= turn)
    return out


def _wrap(theta: FloatArray) -> FloatArray:
    return np.asarray(np.remainder(theta + math.pi, 2 * math.pi) - math.pi)


def _between(a: FloatArray, b: FloatArray) -> FloatArray:
    """Rows ``a^-1 @ b`` of pose rows ``(N, 3)`` (:meth:`Pose2D.between`, vectorised). O(N)."""
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    dx, dy = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
    return np.column_stack([c * dx + s * dy, -s * dx + c * dy, _wrap(b[:, 2] - a[:, 2])])


def _compose(a: FloatArray, b: FloatArray) -> FloatArray:
    """Rows ``a @ b`` of pose rows ``(N, 3)`` (:meth:`Pose2D.__matmul__`, vectorised). O(N)."""
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    return np.column_stack(
        [a[:, 0] + c * b[:, 0] - s * b[:, 1], a[:, 1] + s * b[:, 0] + c * b[:, 1], _wrap(a[:, 2] + b[:, 2])]
    )
