"""A LaserScan-like record (docs/design.md §3) and the Hokuyo URG-04LX beam geometry."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from shared.errors import InvalidInputError
from shared.types.geometry import BoolArray, FloatArray, IntArray
from shared.types.pose import Pose2D

__all__ = ["URG04LX", "BeamGeometry", "Scan"]


@dataclass(frozen=True, slots=True)
class BeamGeometry:
    """Beam layout of a scanner: first beam angle, spacing and count, plus its valid range window.

    The URG-04LX speaks in *steps* of 360/1024 deg with the front at step 384 (docs/design.md §3).
    """

    angle_min_rad: float
    angle_increment_rad: float
    beam_count: int
    range_min_m: float
    range_max_m: float
    rate_hz: float = 10.0

    def angles_rad(self) -> FloatArray:
        """Angle of every beam, counter-clockwise from the scanner's x axis. O(beams)."""
        return self.angle_min_rad + self.angle_increment_rad * np.arange(self.beam_count, dtype=np.float64)

    @classmethod
    def from_steps(
        cls,
        first_step: int,
        last_step: int,
        front_step: int,
        steps_per_turn: int,
        range_min_m: float,
        range_max_m: float,
        rate_hz: float = 10.0,
    ) -> BeamGeometry:
        """Geometry of a SCIP scanner that reports steps ``first_step..last_step`` inclusive."""
        inc = 2.0 * math.pi / steps_per_turn
        return cls(
            (first_step - front_step) * inc,
            inc,
            last_step - first_step + 1,
            range_min_m,
            range_max_m,
            rate_hz,
        )


#: Hokuyo URG-04LX: steps 44..725 of 1024, front at 384 (682 beams, ~240 deg), 10 Hz. Range window
#: 0.02..5.6 m: the paper's Table 1 says 60..4000 mm, the real logs show returns up to ~5.6 m.
URG04LX = BeamGeometry.from_steps(44, 725, 384, 1024, range_min_m=0.02, range_max_m=5.6, rate_hz=10.0)


@dataclass(frozen=True, slots=True)
class Scan:
    """One laser scan in SI units (docs/design.md §3).

    ``ranges_m`` holds one value per beam; NaN or inf mean "no return", as does any value outside
    ``[range_min_m, range_max_m]``. Arrays are copied and made read-only, so a scan is immutable.
    """

    stamp_s: float
    angle_min_rad: float
    angle_increment_rad: float
    range_min_m: float
    range_max_m: float
    ranges_m: FloatArray
    intensities: FloatArray | None = None
    odometry: Pose2D | None = None
    _angles: FloatArray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        given = np.asarray(self.ranges_m)
        if given.ndim > 1:
            raise InvalidInputError(f"Scan.ranges_m has shape {given.shape}: expected one value per beam")
        ranges = np.array(given, dtype=np.float64, copy=True).reshape(-1)
        for name in ("stamp_s", "angle_min_rad", "angle_increment_rad", "range_min_m", "range_max_m"):
            value = float(getattr(self, name))
            if not math.isfinite(value):
                raise InvalidInputError(f"Scan.{name} = {value!r}: expected a finite number")
            object.__setattr__(self, name, value)
        if not 0.0 <= self.range_min_m < self.range_max_m:
            raise InvalidInputError(
                f"Scan range window [{self.range_min_m}, {self.range_max_m}] m: expected 0 <= min < max"
            )
        if self.angle_increment_rad == 0.0:
            raise InvalidInputError("Scan.angle_increment_rad = 0: expected a non-zero beam spacing")
        ranges.setflags(write=False)
        object.__setattr__(self, "ranges_m", ranges)
        if self.intensities is not None:
            inten = np.array(self.intensities, dtype=np.float64, copy=True).reshape(-1)
            if inten.shape != ranges.shape:
                raise InvalidInputError(
                    f"Scan.intensities has {inten.size} values for {ranges.size} beams: expected one per beam"
                )
            inten.setflags(write=False)
            object.__setattr__(self, "intensities", inten)
        angles = self.angle_min_rad + self.angle_increment_rad * np.arange(ranges.size, dtype=np.float64)
        angles.setflags(write=False)
        object.__setattr__(self, "_angles", angles)

    @classmethod
    def from_geometry(
        cls,
        geometry: BeamGeometry,
        ranges_m: ArrayLike,
        stamp_s: float = 0.0,
        odometry: Pose2D | None = None,
    ) -> Scan:
        """A scan with the beam layout of ``geometry`` (e.g. :data:`URG04LX`)."""
        arr = np.asarray(ranges_m, dtype=np.float64)
        if arr.shape != (geometry.beam_count,):
            raise InvalidInputError(
                f"scan has {arr.size} ranges: expected {geometry.beam_count} for this scanner's geometry"
            )
        return cls(
            stamp_s,
            geometry.angle_min_rad,
            geometry.angle_increment_rad,
            geometry.range_min_m,
            geometry.range_max_m,
            arr,
            odometry=odometry,
        )

    @property
    def beam_count(self) -> int:
        """Number of beams."""
        return int(self.ranges_m.size)

    @property
    def angles_rad(self) -> FloatArray:
        """Angle of every beam (read-only array)."""
        return self._angles

    def valid_mask(self) -> BoolArray:
        """Beams with a finite return inside the range window. O(beams)."""
        r = self.ranges_m
        with np.errstate(invalid="ignore"):
            return np.isfinite(r) & (r >= self.range_min_m) & (r <= self.range_max_m)

    def to_points(self) -> tuple[FloatArray, IntArray]:
        """Cartesian points of the valid beams in the scanner frame (paper eq. 13) and their beam indices."""
        idx = np.flatnonzero(self.valid_mask())
        r = self.ranges_m[idx]
        a = self._angles[idx]
        pts = np.empty((idx.size, 2), dtype=np.float64)
        pts[:, 0] = r * np.cos(a)
        pts[:, 1] = r * np.sin(a)
        return pts, idx
