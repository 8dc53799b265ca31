"""The scanner's own range noise, one sigma, as a function of range: what a return is worth to a match.

A scan match that weighs every return alike trusts a wall 5 m away as much as one at 1 m, although a
URG-04LX's range noise grows with range (its datasheet: +-10 mm below 1 m, +-1 % beyond; the project
reads the looser +-25 mm / +-2.5 % as two sigma, as the free-space models do). On a hall whose end walls
sit near the 5.6 m limit those far, noisy returns outvoted the pillars beside the path and pulled the pose
back along it by centimetres per metre. With each return's variance ``sigma_match^2 + sigma_r(range)^2``
the match's information is what the returns carry (a covariance, no threshold on range).

Which scanner made a scan is read from its range window: the URG-04LX class (phase-difference scanners
with a maximum range of at most :data:`SHORT_RANGE_MAX_M`) has range-proportional noise; the long-range
time-of-flight scanners of the benchmark logs (SICK LMS, 50-82 m) have a noise of about a centimetre at
any range, which the match's own ``match_sigma_m`` already holds, so they get no extra term. A pipeline
can be given its model explicitly. (The simulator's :class:`shared.sim.scans.RangeNoise` is the noise it
draws; this one is what the estimator assumes; they need not agree.)

All figures in metres; O(1) per return.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from shared.errors import InvalidInputError
from shared.types import Scan

__all__ = [
    "NO_RANGE_NOISE",
    "SHORT_RANGE_MAX_M",
    "URG04LX_RANGE_NOISE",
    "URG_RANGE_SIGMA_NEAR_M",
    "URG_RANGE_SIGMA_RATIO",
    "RangeNoise",
    "range_noise_for",
]

#: the URG-04LX's range noise, one sigma: its +-25 mm below 1 m and +-2.5 % beyond, read as two sigma
URG_RANGE_SIGMA_NEAR_M = 0.0125
URG_RANGE_SIGMA_RATIO = 0.0125
#: scanners whose maximum range is at most this are of the URG-04LX class (it reports 4.095 or 5.6 m)
SHORT_RANGE_MAX_M = 6.0


@dataclass(frozen=True, slots=True)
class RangeNoise:
    """Range noise ``max(near_m, ratio x range)``, one sigma, in metres."""

    near_m: float = 0.0
    ratio: float = 0.0

    def __post_init__(self) -> None:
        for name in ("near_m", "ratio"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise InvalidInputError(f"RangeNoise.{name} = {value!r}: expected a finite number >= 0")

    def sigma_m(self, range_m: float) -> float:
        """The noise of a return at ``range_m``. O(1)."""
        return max(self.near_m, self.ratio * range_m)


URG04LX_RANGE_NOISE = RangeNoise(URG_RANGE_SIGMA_NEAR_M, URG_RANGE_SIGMA_RATIO)
NO_RANGE_NOISE = RangeNoise()


def range_noise_for(scan: Scan) -> RangeNoise:
    """The range-noise model of the scanner that took ``scan``, from its range window (module
    docstring): the URG-04LX's when its maximum range is at most :data:`SHORT_RANGE_MAX_M`, else none
    beyond the match's own noise. O(1)."""
    return URG04LX_RANGE_NOISE if scan.range_max_m <= SHORT_RANGE_MAX_M else NO_RANGE_NOISE
