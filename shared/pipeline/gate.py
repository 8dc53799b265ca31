"""When the pipeline believes a scan match over odometry, and how it localises against its own map.

Measured on the three SLAM benchmark logs with ``benchmarks/relation_error.py`` (relation error, Kümmerle
et al. 2009, translational mean +- std in m). Before the rework (:meth:`IcpGate.legacy`:
scan-to-scan matching, a plain gate, a 100-step local map) ACES 0.680 +- 2.518, FR079 3.166 +- 6.256, MIT
CSAIL 0.288 +- 0.795; with these defaults 0.165 +- 0.559, 0.048 +- 0.052 and 0.084 +- 0.212 (published
incremental scan matching: 0.173, 0.258, 0.106). The mean is dominated by the long loop relations, so a
single bad step moves it a lot: the old defaults swung by a factor 2 on float-level changes; the new
figures stay below the published ones for local maps of 10-20 m. What the diagnosis found and what each
default answers:

* Fast turns: wheel odometry is off by 3-10 degrees per scan there, the gate refused the (right) ICP
  correction and the heading error stayed for the rest of the run. Now a refused match gets a second
  chance (``rematch``): a correlative search around the prediction (``search_rad``, ``search_m``) and a
  constant-velocity prediction (the last step's estimated motion) seed ICP again, and the best converged
  match is taken when it is good (inlier share >= ``rematch_min_inlier_ratio``) and physically possible
  (``rematch_max_m``, ``rematch_max_rad`` from the keyframe).
* Odometry that stalls and then jumps (MIT CSAIL: several scans without motion, then 50 degrees at once):
  the constant-velocity seed is right where odometry is not. It is only used after a believed match, so
  it never extrapolates a rejected one.
* Along-track creep: point-to-point ICP between scans a few centimetres apart pairs each point with the
  reference return of the same beam and under-estimates the motion (ACES lost 6 % of its path). A keyframe
  renewed every ``keyframe_m`` / ``keyframe_rad`` makes the displacement large against the beam spacing.
* The wall refinement slid along corridors whose walls are a few degrees off parallel (the lateral
  residuals echo, amplified, into the along-track direction): its step now ignores directions the walls
  barely constrain (``refine_degeneracy``, :func:`shared.pipeline.localize.refine_to_walls`).
* Heading drift: the local wall map now spans a travelled distance (``local_map_m``) instead of a step
  count, so slow logs (ACES, ~4 cm per scan) keep their walls for as long as fast ones (MIT, ~20 cm).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["IcpGate"]


@dataclass(frozen=True, slots=True)
class IcpGate:
    """When an ICP correction is trusted over odometry, and when the reference scan (keyframe) moves on.

    Scans are matched against the last keyframe, renewed every ``keyframe_m`` metres or ``keyframe_rad``
    of turn (0: every scan, i.e. scan-to-scan matching) and whenever a match is refused. A correction
    farther than ``max_correction_m`` or ``max_correction_rad`` from the odometry prediction, or with an
    inlier share below ``min_inlier_ratio``, is not taken as it is: with ``rematch`` on it gets the second
    chance described in the module docstring (:func:`shared.pipeline.rematch.rematch`), otherwise odometry
    stands. ``correction_ratio`` widens the gate by that share of the step's own odometry motion; the
    ``strong_*`` options accept a larger correction when the match is excellent (converged, inlier share >=
    ``strong_inlier_ratio``, RMS <= ``strong_rmse_m``, within ``strong_max_m``/``strong_max_rad``); both
    are off by default (before the scan-matching rework they moved single logs a lot in either direction).

    With ``refine_to_map`` the pose is then refined against a local wall map (points within
    ``refine_range_m``; kept when at least ``refine_min_share`` of them found a wall and the correction
    passes the gate). Two maps restart in turn every ``local_map_steps`` steps or ``local_map_m`` metres of
    odometry travel, whichever comes first, and the older one is matched against.

    With ``fuse_odometry`` (on by default) a believed match (not a second-chance one: there odometry was
    found wrong) is fused with the odometry motion since the keyframe by their information
    (:mod:`shared.pipeline.fusion`): odometry's standard deviations ``odom_sigma_m + odom_sigma_ratio x
    distance`` and ``odom_sigma_rad + odom_sigma_rad_per_rad x turn``, scaled by factors the pipeline learns
    from its own matches (:mod:`shared.pipeline.odonoise`: the simulator's wheels come out at 0.05-0.2 of
    that model's variance, the benchmark logs' at 0.1-1.7), the scan's ``match_sigma_m`` per point-to-line
    residual. Where the scan fixes a direction far better than odometry and the two disagree by more than
    ``odom_huber`` learned standard deviations, odometry counts less (Huber). Along a corridor whose ends
    are out of range the pose then follows the wheels (a simulated 19 m corridor: 0.79 m short without the
    fusion, 4 cm with it); on the benchmark logs (the same session) the fixed model gave ACES 0.168,
    Freiburg 079 0.060, MIT CSAIL 0.131 against 0.165, 0.048, 0.084 unfused, the learned factors 0.161,
    0.045, 0.086 (these figures swing by a third on float-level changes).
    A fused pose must agree with the linear fusion of the match and odometry (their information-weighted
    mean, :func:`shared.pipeline.fusion_solve.linear_fusion`) within ``fusion_chi2`` (the squared Mahalanobis
    distance under the posterior information; 11.34 is chi-square's 99 % point for 3 degrees of freedom);
    one farther off (Gauss-Newton's point-to-line associations pulled it beyond both, 4 cm short of the
    match and odometry alike in a simulated hall) is replaced by the linear fusion. Only for scanners with
    a range-noise model, whose scan information is calibrated; 0 turns the test off.
    With ``refine_with_odometry`` the wall refinement's directions that the walls barely constrain
    (``refine_degeneracy``) move towards the odometry prediction by its share of the information along
    them, under the same noise figures (translation only) (:func:`shared.pipeline.localize.refine_to_walls`;
    not after a second-chance match). It is off: on the suite it added little to the fused scan match and
    made people worlds worse (4 worlds, ATE 0.067 m against 0.047 m fused alone).
    """

    min_inlier_ratio: float = 0.5
    max_correction_m: float = 0.1
    max_correction_rad: float = 0.05
    correction_ratio: float = 0.0
    refine_range_m: float = 1000.0
    strong_inlier_ratio: float = 2.0  # > 1: off
    strong_rmse_m: float = 0.03
    strong_max_m: float = 0.5
    strong_max_rad: float = 0.3
    keyframe_m: float = 0.15
    keyframe_rad: float = 0.05
    refine_to_map: bool = True
    local_map_steps: int = 1000
    local_map_m: float = 15.0
    refine_min_share: float = 0.5
    refine_degeneracy: float = 0.05
    rematch: bool = True
    rematch_min_inlier_ratio: float = 0.65
    rematch_margin: float = 0.05
    rematch_max_m: float = 1.0
    rematch_max_rad: float = 1.0
    search_rad: float = 0.35
    search_m: float = 0.2
    constant_velocity: bool = True
    fuse_odometry: bool = True
    refine_with_odometry: bool = False
    odom_sigma_m: float = 0.01
    odom_sigma_ratio: float = 0.05
    odom_sigma_rad: float = 0.01
    odom_sigma_rad_per_rad: float = 0.1
    match_sigma_m: float = 0.02
    odom_huber: float = 3.0
    fusion_chi2: float = 11.34

    @classmethod
    def legacy(cls) -> IcpGate:
        """The behaviour before the scan-matching rework (scan-to-scan, no second chance, 100-step local map),
        to compare."""
        return cls(
            keyframe_m=0.0,
            keyframe_rad=0.0,
            local_map_steps=100,
            local_map_m=float("inf"),
            refine_degeneracy=0.0,
            rematch=False,
        )
