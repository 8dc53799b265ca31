"""Line-segment EKF-SLAM: the classic baseline the paper compares its mapping with (§6.3, Fig. 24).

This module is the filter (prediction, update, state augmentation, pruning); its settings are
:class:`~shared.baselines.ekf_params.EkfLineSlamParams`.

**State** ``x = [x, y, theta, rho_1, alpha_1, ..., rho_L, alpha_L]``: the robot pose (m, m, rad) and one
infinite line per landmark in the world frame (Hesse normal form, ``rho >= 0``, ``alpha`` in ``(-pi, pi]``),
with the full covariance ``P`` ``(n, n)``, ``n = 3 + 2 L``. The map frame is anchored at the initial pose
(``P`` starts at zero).

**Prediction** from odometry: ``u = prev_odom.between(odom)`` = ``(dx, dy, dtheta)`` in the robot frame,
``pose' = pose @ u``, ``P_rr' = F P_rr F^T + W Q W^T``, ``P_rl' = F P_rl`` with ``F = d pose'/d pose``,
``W = d pose'/d u`` and ``Q = diag(s_t^2, s_t^2, s_r^2)`` where::

    s_t = trans_noise_per_m |d| + trans_noise_per_rad |dtheta| + min_trans_sigma_m
    s_r = rot_noise_per_m |d| + rot_noise_per_rad |dtheta| + min_rot_sigma_rad,   |d| = hypot(dx, dy)

O(n) per step.

**Observation**: lines extracted from the scan by :func:`~shared.baselines.split_merge.extract_lines`
(scanner frame, with a 2x2 covariance each), and the measurement model of
:mod:`~shared.baselines.line_model` (scanner at ``pose @ laser_offset``).

**Data association** (:mod:`~shared.baselines.ekf_associate`), vectorised over the M observations x L
landmarks: innovation ``v = z - h(x)`` with the angle wrapped and the rho sign flip handled
(:func:`~shared.baselines.line_model.line_difference`), ``S = H P H^T + R`` and the squared Mahalanobis
distance ``v^T S^-1 v``; pairs within ``gate_chi2`` are assigned greedily, nearest first, each landmark and
each observation at most once. O(M L + L).

**Update** with all matched observations stacked at once: ``K = P H^T S^-1``, ``x += K v``,
``P -= K S K^T``, then ``P`` symmetrised. O(n^2 k) for k matches: the per-step cost grows with the number of
landmarks, which is the point of the paper's Fig. 24 (no sub-mapping here).

**New landmarks**: an unmatched observation whose Mahalanobis distance to every landmark exceeds
``new_landmark_chi2`` is added (state augmentation with ``g(x, z)`` and its Jacobians:
``P_ll = G_r P_rr G_r^T + G_z R G_z^T``, ``P_lx = G_r P_rx``); two such observations of one scan that gate
with each other make one landmark. An unmatched observation within the gate of a landmark another
observation of the scan already used only extends that landmark's extent; one between the gates is
ignored as ambiguous.

**Extents** (:mod:`~shared.baselines.ekf_extents`): the observed end points, put in the world with the
corrected pose, are kept per landmark as world pieces; on each new sighting they are projected on the
current line (coordinate ``t`` along ``d = (-sin alpha, cos alpha)``, ``point = rho n + t d``) and intervals
closer than ``extent_gap_m`` are joined, so an opening wider than that (a doorway between collinear walls)
stays open. (Not stored as ``t``: the foot of the normal slides by ``rho * d_alpha`` as ``alpha`` is
corrected.) :meth:`EkfLineSlam.walls` gives one segment per interval of every landmark observed at least
``min_observations`` times.

**Pruning** (classic landmark-quality bookkeeping, not sub-mapping): a landmark still seen in fewer than
``min_observations`` scans ``prune_after_steps`` steps after its creation (a one-off fit across a corner,
clutter that happened to line up) is deleted: its rows and columns leave ``x`` and ``P``, which is exact
marginalisation for a Gaussian. Every other landmark stays in the state for good.
"""

from __future__ import annotations

import math
import time

import numpy as np

from shared.baselines.ekf_associate import associate
from shared.baselines.ekf_extents import extent_intervals, join_extent
from shared.baselines.ekf_params import EkfLineSlamParams
from shared.baselines.line_model import line_difference, lines_to_world, wrap_angles
from shared.baselines.split_merge import LineObservations, extract_lines
from shared.types import FloatArray, IntArray, Pose2D, Scan, segments_from_hesse

__all__ = ["EkfLineSlam"]


class EkfLineSlam:
    """Line-segment EKF-SLAM run one scan at a time, like :class:`~shared.pipeline.Pipeline` (module doc).

    ``laser_offset`` is the scanner's pose in the robot frame (as for the pipeline; the simulated robot's is
    ``run.drive.laser_offset``). ``initial_pose`` defaults to the first scan's odometry (else the origin).
    ``step_ms`` holds the wall time of every step (``time.perf_counter``), in milliseconds, and
    ``extract_ms`` the part of it spent in line extraction (the front end; the rest is the filter).
    """

    def __init__(
        self,
        params: EkfLineSlamParams | None = None,
        initial_pose: Pose2D | None = None,
        *,
        laser_offset: Pose2D | None = None,
    ) -> None:
        self.params = params or EkfLineSlamParams()
        self.laser_offset = laser_offset or Pose2D()
        self._initial = initial_pose
        self._x = np.zeros(3)
        self._P = np.zeros((3, 3))
        self._started = False
        self._prev_odom: Pose2D | None = None
        self._extents: list[FloatArray] = []  # per landmark: observed pieces (K, 4), world frame
        self._seen: list[int] = []
        self._born: list[int] = []
        self._steps = 0
        self.pruned = 0  # landmarks deleted by pruning, all steps
        self._trajectory: list[tuple[float, Pose2D]] = []
        self.step_ms: list[float] = []
        self.extract_ms: list[float] = []
        self.matched = 0  # observations used in EKF updates, all steps
        self.extent_only = 0  # observations that only extended a landmark already matched in their scan
        self.ignored = 0  # observations between the gates

    # ------------------------------------------------------------------ read-only views
    @property
    def pose(self) -> Pose2D:
        """The current robot pose estimate (world frame)."""
        return Pose2D(float(self._x[0]), float(self._x[1]), float(self._x[2]))

    @property
    def n_landmarks(self) -> int:
        """Number of line landmarks in the state."""
        return (self._x.size - 3) // 2

    @property
    def landmarks(self) -> FloatArray:
        """``(L, 2)`` ``[rho_m, alpha_rad]`` of every landmark (world frame), a copy."""
        return self._x[3:].reshape(-1, 2).copy()

    @property
    def covariance(self) -> FloatArray:
        """The full state covariance ``(3 + 2 L, 3 + 2 L)``, a copy."""
        return self._P.copy()

    @property
    def observation_counts(self) -> IntArray:
        """How many scans saw each landmark ``(L,)`` (EKF updates, creation and extent-only sightings)."""
        return np.array(self._seen, dtype=np.intp)

    @property
    def trajectory(self) -> list[tuple[float, Pose2D]]:
        """``(stamp_s, pose)`` after every step, in order (a copy of the list)."""
        return list(self._trajectory)

    def walls(self) -> FloatArray:
        """Map segments ``(W, 4)`` ``[x0, y0, x1, y1]`` (m): each extent interval of every landmark observed
        at least ``min_observations`` times. O(L + intervals)."""
        lm = self._x[3:].reshape(-1, 2)
        rho: list[float] = []
        alpha: list[float] = []
        t0: list[float] = []
        t1: list[float] = []
        for j, pieces in enumerate(self._extents):
            if self._seen[j] < self.params.min_observations or not len(pieces):
                continue
            lo, hi = extent_intervals(pieces, float(lm[j, 1]))
            rho.extend([float(lm[j, 0])] * len(lo))
            alpha.extend([float(lm[j, 1])] * len(lo))
            t0.extend(lo.tolist())
            t1.extend(hi.tolist())
        if not rho:
            return np.zeros((0, 4))
        return segments_from_hesse(rho, alpha, t0, t1)

    # ------------------------------------------------------------------ the step
    def step(self, scan: Scan) -> Pose2D:
        """Predict from the scan's odometry, extract lines, associate, update, add landmarks, extend.

        A scan without odometry (or the first one) predicts no motion (only the noise floors on later
        steps). Returns the corrected pose. O(M L + n^2 k), see the module docstring.
        """
        t_start = time.perf_counter()
        odom = scan.odometry
        if not self._started:
            start = self._initial or odom or Pose2D()
            self._x[:3] = start.as_tuple()
            self._started = True
        else:
            motion = (
                self._prev_odom.between(odom) if (odom is not None and self._prev_odom is not None) else None
            )
            self._predict(motion or Pose2D())
        if odom is not None:
            self._prev_odom = odom
        t_extract = time.perf_counter()
        obs = extract_lines(scan, self.params.extraction)
        self.extract_ms.append((time.perf_counter() - t_extract) * 1e3)
        if len(obs):
            self._observe(obs)
        self._prune()
        self._steps += 1
        pose = self.pose
        self._trajectory.append((scan.stamp_s, pose))
        self.step_ms.append((time.perf_counter() - t_start) * 1e3)
        return pose

    def _predict(self, u: Pose2D) -> None:
        p = self.params
        th = float(self._x[2])
        c, s = math.cos(th), math.sin(th)
        dx, dy, dth = u.x_m, u.y_m, u.theta_rad
        self._x[0] += c * dx - s * dy
        self._x[1] += s * dx + c * dy
        self._x[2] = wrap_angles(th + dth)
        F = np.array([[1.0, 0.0, -s * dx - c * dy], [0.0, 1.0, c * dx - s * dy], [0.0, 0.0, 1.0]])
        W = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        dist = math.hypot(dx, dy)
        turn = abs(dth)
        s_t = p.trans_noise_per_m * dist + p.trans_noise_per_rad * turn + p.min_trans_sigma_m
        s_r = p.rot_noise_per_m * dist + p.rot_noise_per_rad * turn + p.min_rot_sigma_rad
        Q = np.diag([s_t * s_t, s_t * s_t, s_r * s_r])
        P = self._P
        P[:3, :3] = F @ P[:3, :3] @ F.T + W @ Q @ W.T
        if P.shape[0] > 3:
            P[:3, 3:] = F @ P[:3, 3:]
            P[3:, :3] = P[:3, 3:].T

    def _measurement_cov(self, obs: LineObservations) -> FloatArray:
        R = obs.covariance.copy()
        R[:, 0, 0] += self.params.min_rho_sigma_m**2
        R[:, 1, 1] += self.params.min_alpha_sigma_rad**2
        return R

    def _observe(self, obs: LineObservations) -> None:
        p = self.params
        R = self._measurement_cov(obs)
        m = len(obs)
        z = np.stack([obs.rho_m, obs.alpha_rad], axis=1)
        found = associate(self._x, self._P, self.laser_offset, z, R, p.gate_chi2)
        pairs, best, best_j = found.pairs, found.best, found.best_j
        if pairs:
            self._update(pairs, found.v, found.Hr, found.Hl, R)
        matched_obs = {i for i, _ in pairs}
        self.matched += len(pairs)
        for _, j in pairs:
            self._seen[j] += 1
        # extents of the matched landmarks (with the corrected pose)
        for i, j in pairs:
            self._extend(j, obs.endpoints[i])
        # new landmarks and extent-only sightings
        touched = {j for _, j in pairs}
        new_obs: list[int] = []
        for i in range(m):
            if i in matched_obs:
                continue
            if best[i] > p.new_landmark_chi2:
                new_obs.append(i)
            elif best[i] <= p.gate_chi2 and int(best_j[i]) in touched:
                self._extend(int(best_j[i]), obs.endpoints[i])
                self.extent_only += 1
            else:
                self.ignored += 1
        if new_obs:
            self._add_landmarks(obs, R, sorted(new_obs, key=lambda i: -int(obs.n_points[i])))

    def _update(
        self, pairs: list[tuple[int, int]], v: FloatArray, Hr: FloatArray, Hl: FloatArray, R: FloatArray
    ) -> None:
        """Stacked EKF update with k matched pairs: ``v`` (k, 2), ``Hr`` (k, 2, 3), ``Hl`` (k, 2, 2)."""
        k = len(pairs)
        n = self._x.size
        H = np.zeros((2 * k, n))
        Rk = np.zeros((2 * k, 2 * k))
        for q, (i, j) in enumerate(pairs):
            H[2 * q : 2 * q + 2, :3] = Hr[q]
            c = 3 + 2 * j
            H[2 * q : 2 * q + 2, c : c + 2] = Hl[q]
            Rk[2 * q : 2 * q + 2, 2 * q : 2 * q + 2] = R[i]
        PHt = self._P @ H.T
        S = H @ PHt + Rk
        S = 0.5 * (S + S.T)
        K = np.linalg.solve(S, PHt.T).T
        self._x += K @ v.reshape(-1)
        self._P -= K @ S @ K.T
        self._P = 0.5 * (self._P + self._P.T)
        self._x[2] = wrap_angles(self._x[2])
        self._normalise_landmarks()

    def _normalise_landmarks(self) -> None:
        """Keep ``rho >= 0`` and ``alpha`` wrapped; a flip negates the rho row and column of P."""
        lm = self._x[3:].reshape(-1, 2)
        lm[:, 1] = wrap_angles(lm[:, 1])
        for j in np.flatnonzero(lm[:, 0] < 0.0).tolist():
            lm[j, 0] = -lm[j, 0]
            lm[j, 1] = float(wrap_angles(lm[j, 1] + math.pi))
            r = 3 + 2 * j
            self._P[r, :] *= -1.0
            self._P[:, r] *= -1.0

    def _extend(self, j: int, endpoints: FloatArray) -> None:
        """Add scanner-frame end points ``[x0, y0, x1, y1]`` seen from the current pose to landmark ``j``."""
        laser = self.pose @ self.laser_offset
        new = laser.transform_points(endpoints.reshape(2, 2)).reshape(4)
        rho, alpha = float(self._x[3 + 2 * j]), float(self._x[4 + 2 * j])
        self._extents[j] = join_extent(self._extents[j], new, rho, alpha, self.params.extent_gap_m)

    def _add_landmarks(self, obs: LineObservations, R: FloatArray, candidates: list[int]) -> None:
        """Augment the state with the observations ``candidates`` (largest first), one landmark per line."""
        p = self.params
        g, G_r, G_z = lines_to_world(
            self._x[:3], self.laser_offset, obs.rho_m[candidates], obs.alpha_rad[candidates]
        )
        accepted: list[int] = []  # positions in `candidates`
        owner: dict[int, int] = {}  # candidate position -> landmark index
        for q, i in enumerate(candidates):
            twin = -1
            for a in accepted:
                ia = candidates[a]
                d_rho, d_alpha, sign = line_difference(
                    obs.rho_m[i], obs.alpha_rad[i], obs.rho_m[ia], obs.alpha_rad[ia]
                )
                s = float(sign)
                C = R[i] + R[ia] * np.array([[1.0, s], [s, 1.0]])
                d = np.array([float(d_rho), float(d_alpha)])
                if float(d @ np.linalg.solve(C, d)) <= p.gate_chi2:
                    twin = a
                    break
            if twin >= 0:
                self._extend(owner[twin], obs.endpoints[i])
                self.extent_only += 1
                continue
            accepted.append(q)
            owner[q] = self._augment(g[q], G_r[q], G_z[q], R[i])
            self._extend(owner[q], obs.endpoints[i])

    def _augment(self, g: FloatArray, G_r: FloatArray, G_z: FloatArray, R: FloatArray) -> int:
        """Append one landmark ``g = [rho, alpha]`` with its cross-covariances; returns its index. O(n^2)."""
        n = self._x.size
        P = np.zeros((n + 2, n + 2))
        P[:n, :n] = self._P
        P_rx = self._P[:3, :]
        P[n:, :n] = G_r @ P_rx
        P[:n, n:] = P[n:, :n].T
        P[n:, n:] = G_r @ self._P[:3, :3] @ G_r.T + G_z @ R @ G_z.T
        self._P = P
        self._x = np.concatenate([self._x, g])
        self._extents.append(np.zeros((0, 4)))
        self._seen.append(1)
        self._born.append(self._steps)
        return self.n_landmarks - 1

    def _prune(self) -> None:
        """Delete landmarks seen in < ``min_observations`` scans ``prune_after_steps`` steps after birth."""
        p = self.params
        if p.prune_after_steps == 0:
            return
        drop = [
            j
            for j in range(self.n_landmarks)
            if self._seen[j] < p.min_observations and self._steps - self._born[j] >= p.prune_after_steps
        ]
        if not drop:
            return
        keep = np.ones(self._x.size, dtype=bool)
        for j in drop:
            keep[3 + 2 * j : 5 + 2 * j] = False
        self._x = self._x[keep]
        self._P = self._P[np.ix_(keep, keep)]
        gone = set(drop)
        self._extents = [e for j, e in enumerate(self._extents) if j not in gone]
        self._seen = [c for j, c in enumerate(self._seen) if j not in gone]
        self._born = [b for j, b in enumerate(self._born) if j not in gone]
        self.pruned += len(drop)
