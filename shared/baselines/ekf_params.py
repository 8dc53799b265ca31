"""Settings of the line-segment EKF-SLAM baseline (:class:`~shared.baselines.ekf_lines.EkfLineSlam`,
paper §6.3): motion noise, association gates, measurement floors, extent joining and pruning, validated on
construction. Units: m, rad, and squared Mahalanobis distances (dimensionless). O(fields) to validate.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

from shared.baselines.errors import BaselineParameterError, check_number
from shared.baselines.split_merge import SplitMergeParams

__all__ = ["EkfLineSlamParams"]


@dataclass(frozen=True, slots=True)
class EkfLineSlamParams:
    """Settings of :class:`EkfLineSlam`, validated on construction (errors name the field).

    Motion noise (standard deviations per step, module docstring): ``trans_noise_per_m`` (m per m driven),
    ``trans_noise_per_rad`` (m per rad turned), ``rot_noise_per_m`` (rad per m), ``rot_noise_per_rad``
    (rad per rad), plus floors ``min_trans_sigma_m`` / ``min_rot_sigma_rad``. Association:
    ``gate_chi2`` (squared Mahalanobis distance to match; 9.21 = chi-square 2 dof 99 %) and
    ``new_landmark_chi2`` (>= ``gate_chi2``; farther than this from every landmark makes a new one).
    Measurement: the extractor's covariance is floored at ``min_rho_sigma_m`` / ``min_alpha_sigma_rad``
    (added in quadrature: on simulated runs the fits' own covariances are ~1.7x optimistic, and a total
    least squares fit of a wall seen obliquely is biased by range noise along the beams; without the floors
    a long run past small boxes drifts worse than odometry). Map output: ``extent_gap_m``,
    ``min_observations``. Pruning: a landmark seen in fewer than ``min_observations`` scans
    ``prune_after_steps`` steps after its creation is deleted from the state (0 keeps every landmark).
    """

    extraction: SplitMergeParams = field(default_factory=SplitMergeParams)
    trans_noise_per_m: float = 0.05
    trans_noise_per_rad: float = 0.01
    rot_noise_per_m: float = 0.1
    rot_noise_per_rad: float = 0.05
    min_trans_sigma_m: float = 0.001
    min_rot_sigma_rad: float = 0.001
    gate_chi2: float = 9.21
    new_landmark_chi2: float = 50.0
    min_rho_sigma_m: float = 0.03
    min_alpha_sigma_rad: float = 0.02
    extent_gap_m: float = 0.5
    min_observations: int = 3
    prune_after_steps: int = 20

    def __post_init__(self) -> None:
        owner = type(self).__name__
        if not isinstance(self.extraction, SplitMergeParams):
            raise BaselineParameterError(owner, "extraction", self.extraction, "a SplitMergeParams")
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "extraction":
                continue
            if f.name == "min_observations":
                check_number(owner, f.name, value, minimum=1, inclusive=True, integer=True)
            elif f.name == "prune_after_steps":
                check_number(owner, f.name, value, inclusive=True, integer=True)
            elif f.name in ("gate_chi2", "new_landmark_chi2", "extent_gap_m"):
                check_number(owner, f.name, value)
            else:
                check_number(owner, f.name, value, inclusive=True)
        if self.new_landmark_chi2 < self.gate_chi2:
            raise BaselineParameterError(
                owner, "new_landmark_chi2", self.new_landmark_chi2, f">= gate_chi2 ({self.gate_chi2:g})"
            )
