"""Loop-closure settings: what an operator may tune, declared as data and validated where they are built.

Every figure is in SI units (metres, radians). The defaults suit the URG-04LX class (5.6 m range) and the
benchmark logs' long-range scanners alike; :meth:`LoopClosureSettings.parse` takes a mapping of field names
(from a configuration file or a control message) and names each bad field in its error.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

from shared.slam.errors import LoopClosureSettingsError

__all__ = ["LoopClosureSettings"]

#: (low, high) per numeric field: both inclusive
_RANGES: dict[str, tuple[float, float]] = {
    "keyframe_m": (0.05, 10.0),
    "keyframe_rad": (0.02, math.pi),
    "search_radius_m": (0.0, 100.0),
    "recent_m": (0.0, 1000.0),
    "window_m": (0.0, 10.0),
    "window_rad": (0.0, math.pi),
    "min_inlier_share": (0.0, 1.0),
    "inlier_m": (0.005, 1.0),
    "submap_keyframes": (0, 50),
    "max_candidates": (1, 50),
    "robust_sigmas": (0.1, 100.0),
    "max_view_change_rad": (0.0, math.pi),
}


@dataclass(frozen=True, slots=True)
class LoopClosureSettings:
    """How the pose graph takes keyframes and closes loops (see :mod:`shared.slam.mapper`).

    - ``enabled``: search for loop closures at all (off: the graph holds the front end's chain only, the
      map is the front end's);
    - ``keyframe_m`` / ``keyframe_rad``: a new keyframe after this much travel or turn since the last one;
    - ``search_radius_m``: earlier keyframes within this distance of the current pose are candidates;
    - ``recent_m``: keyframes fewer than this many metres of travel back are not (they are the chain);
    - ``window_m`` / ``window_rad``: the half-width of the correlative search round the graph's guess
      (the drift a loop may have accumulated; a loop beyond it is not found);
    - ``min_inlier_share``: share of the current scan's returns within ``inlier_m`` of the candidate's
      submap for the match to count as a loop closure;
    - ``submap_keyframes``: keyframes either side of the candidate that its submap holds;
    - ``max_candidates``: candidates tried per keyframe, nearest first;
    - ``robust_sigmas``: the Cauchy kernel's width on loop edges, in standard deviations: a loop edge
      whose residual is far beyond it counts for almost nothing (a false closure does not wreck the map);
    - ``max_view_change_rad``: a candidate seen with a heading this different is no candidate (from the
      opposite side a scan returns from other faces of every recess, box and door jamb, the features that
      fix the pose along a corridor, and the match is biased there);
    - ``final_batch``: offline, one batch optimisation of the whole graph at the end.
    """

    enabled: bool = True
    keyframe_m: float = 0.5
    keyframe_rad: float = 0.35
    search_radius_m: float = 4.0
    recent_m: float = 10.0
    window_m: float = 2.5
    window_rad: float = 0.35
    min_inlier_share: float = 0.5
    inlier_m: float = 0.08
    submap_keyframes: int = 3
    max_candidates: int = 2
    robust_sigmas: float = 3.0
    max_view_change_rad: float = math.pi / 2
    final_batch: bool = True

    def __post_init__(self) -> None:
        problems: list[str] = []
        bad: list[str] = []
        for f in fields(self):
            before = len(problems)
            value = getattr(self, f.name)
            if f.name in ("enabled", "final_batch"):
                if not isinstance(value, bool):
                    problems.append(f"{f.name} = {value!r}: expected true or false")
                continue
            low, high = _RANGES[f.name]
            integral = f.name in ("submap_keyframes", "max_candidates")
            kind_ok = isinstance(value, int) if integral else isinstance(value, int | float)
            if isinstance(value, bool) or not kind_ok:
                expected = "an integer" if integral else "a number"
                problems.append(f"{f.name} = {value!r}: expected {expected} in [{low:g}, {high:g}]")
            elif not (math.isfinite(value) and low <= value <= high):
                problems.append(f"{f.name} = {value!r}: expected a value in [{low:g}, {high:g}]")
            if len(problems) > before:
                bad.append(f.name)
        if problems:
            raise LoopClosureSettingsError(
                "invalid loop-closure settings: " + "; ".join(problems), tuple(bad)
            )

    @classmethod
    def parse(cls, data: Mapping[str, Any]) -> LoopClosureSettings:
        """Settings from a mapping of field names; unknown names are refused with the known ones listed."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise LoopClosureSettingsError(
                f"unknown loop-closure setting(s) {', '.join(unknown)}: "
                f"expected some of {', '.join(sorted(known))}",
                tuple(unknown),
            )
        return cls(**dict(data))

    def as_dict(self) -> dict[str, Any]:
        """The settings as a plain mapping (round-trips through :meth:`parse`)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}
