"""Places: what the robot's loop closure keeps of a building it drives again and again.

Without this, every keyframe keeps its scan (for loop searches) and every scan kept for redraws stays
(one each 10 cm), so the mapping state and each rebuild of the map grow with the distance driven: about
3.6 MB per lap of the simulated corridor loop, 3 GB a day. Yet a scan taken where newer ones were taken,
facing the same way, adds nothing to the map that the newer ones do not see (and the newer ones see the
building as it is now: moved furniture, a door that was opened). So once the graph has tied the robot's
current stretch to the earlier visit (a loop closure accepted within :data:`TIED_KEYFRAMES` keyframes:
the estimate of where it is is then good), a keyframe whose place (within half the keyframe spacing and
the keyframe turn) an older held keyframe holds **retires** once the robot is far enough past it that no
sequential or skip edge reads its scan any more (:func:`superseded`), and each new kept scan retires the
older kept scans at its place (within :data:`SCAN_PLACE`) beyond the newest :data:`SCANS_PER_PLACE`
there. A retired keyframe is no longer a loop-search candidate and gives up its scan, and it leaves the
graph's solver: it rides on the place's held keyframe, its edges carried onto that one
(:mod:`shared.slam.riders`); a retired kept scan is not mapped again by later rebuilds and gives up its
returns.

**The place keeps its first keyframe, the map its newest scans.** Until 2026-12-07 the newest keyframe
retired the older ones: each lap was then matched against the lap before, and the small error of every
such match was passed on to the next lap, so the map drifted as a whole in the world's frame (0.1 degree
and 3 cm in 7 laps of the corridor loop; held keyframes 5.3 cm off the truth and completeness down from
99.7 to 85 % after 30 laps, 37 % after 70). Now every visit is matched against the same reference, the
first keyframe at the place, which the first lap tied to the graph's anchor, so those errors no longer
add up; the redraws still map the newest kept scans (the building as it is now). What is held and solved
is then bounded by the places visited (area x headings), not by the distance driven. The idea is the
reduced pose graph's (Johannsson et al., ICRA 2013: "Temporally scalable visual SLAM using a reduced pose
graph"); what still grows with distance is a few rows per keyframe (its front-end pose, its rider offset,
its sequential covariance) and one record per closure.

**The same map whatever the timing.** Retirements are decided in the step (at the join of a keyframe's
loop search, a fixed step), numbered in order; a job (a loop search, a rebuild) reads only what was held
when it began (``held_upto``: the number of retirements then), and a retired item's data is freed only
once no pending job began before its retirement (:meth:`Places.free_upto`). So when the data is freed
changes the state's size, never the map.

Cost: O(keyframes + kept scans) per keyframe, vectorised (masks over every row, distances only among the
held ones near the new keyframe's scans), in the step.
"""

from __future__ import annotations

import math

import numpy as np

from shared.pipeline.wallmap import MergeTolerances
from shared.slam.rows import Rows
from shared.types import BoolArray, FloatArray, IntArray

__all__ = ["SCANS_PER_PLACE", "SCAN_PLACE", "TIED_KEYFRAMES", "Places", "near", "superseded"]

#: kept scans within this distance (m) and turn (rad) of a newer one are at its place
SCAN_PLACE = (0.10, math.radians(15.0))
#: a place holds this many kept scans, the newest: as many as the wall map needs to show a wall
#: (:class:`shared.pipeline.wallmap.MergeTolerances` ``min_observations``), so a short wall seen from one
#: place only, lap after lap, is still drawn by a rebuild (with one scan a place it dropped below)
SCANS_PER_PLACE = MergeTolerances().min_observations
#: the graph ties the robot's stretch to an earlier visit while a loop closure was accepted at most this
#: many keyframes back (5 m at the default 0.5 m spacing)
TIED_KEYFRAMES = 10

_HELD = math.inf


class Places:
    """Which keyframes and kept scans are held, and the order they were retired in (module docstring).

    Per keyframe and per kept scan: the number of its retirement (``inf`` while held). ``enabled`` False
    (offline mapping) keeps everything."""

    __slots__ = (
        "enabled",
        "freed_keyframes",
        "freed_scans",
        "key_retired",
        "keyframe_order",
        "scan_order",
        "scan_retired",
    )

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled
        self.key_retired = Rows(1)
        self.scan_retired = Rows(1)
        self.keyframe_order: list[int] = []  # keyframes in the order retired
        self.scan_order: list[int] = []  # kept scans in the order retired
        self.freed_keyframes = 0  # how many of keyframe_order gave up their data
        self.freed_scans = 0

    @property
    def keyframes_retired(self) -> int:
        return len(self.keyframe_order)

    @property
    def scans_retired(self) -> int:
        return len(self.scan_order)

    def add_keyframe(self) -> None:
        self.key_retired.append((_HELD,))

    def add_scan(self) -> None:
        self.scan_retired.append((_HELD,))

    def keyframes_held(self, upto: int | None = None) -> BoolArray:
        """``(K,)``: which keyframes were held when ``upto`` keyframes had been retired (None: now)."""
        col = self.key_retired.view()[:, 0]
        return np.asarray(col >= (len(self.keyframe_order) if upto is None else upto))

    def scans_held(self, upto: int | None = None) -> BoolArray:
        """``(N,)``: which kept scans were held when ``upto`` kept scans had been retired (None: now)."""
        col = self.scan_retired.view()[:, 0]
        return np.asarray(col >= (len(self.scan_order) if upto is None else upto))

    def retire_keyframes(self, indices: IntArray) -> None:
        for i in indices.tolist():
            self.key_retired.data[i, 0] = len(self.keyframe_order)
            self.keyframe_order.append(int(i))

    def retire_scans(self, indices: IntArray) -> None:
        for i in indices.tolist():
            self.scan_retired.data[i, 0] = len(self.scan_order)
            self.scan_order.append(int(i))

    def free_upto(self, keyframes: int, scans: int) -> tuple[list[int], list[int]]:
        """The keyframes and kept scans retired before the ``keyframes``-th and ``scans``-th retirement
        whose data is not freed yet (the caller frees it); they are marked freed."""
        keys = self.keyframe_order[self.freed_keyframes : keyframes]
        scans_out = self.scan_order[self.freed_scans : scans]
        self.freed_keyframes = max(self.freed_keyframes, keyframes)
        self.freed_scans = max(self.freed_scans, scans)
        return keys, scans_out


def near(
    poses: FloatArray, among: IntArray, target: FloatArray, radius_m: float, turn_rad: float
) -> IntArray:
    """Those of ``among`` (indices into ``poses`` ``(N, 3)``) within ``radius_m`` of ``target`` ``(3,)``
    and turned at most ``turn_rad`` from it. O(len(among))."""
    if not len(among):
        return among
    rows = poses[among]
    dist = np.hypot(rows[:, 0] - target[0], rows[:, 1] - target[1])
    turn = np.abs(np.remainder(rows[:, 2] - target[2] + np.pi, 2 * np.pi) - np.pi)
    out: IntArray = among[(dist <= radius_m) & (turn <= turn_rad)]
    return out


def superseded(
    estimate: FloatArray,
    travelled: FloatArray,
    held: BoolArray,
    pairs: FloatArray,
    indices: range,
    gap_m: float,
    place: tuple[float, float],
) -> list[tuple[int, int]]:
    """Which of the keyframes ``indices`` retire, each with the keyframe it rides on: a held one whose
    stretch a loop closure tied to an earlier visit (a closure of ``pairs`` ``(C, 2)``, rows ``[current,
    candidate]``, made at most :data:`TIED_KEYFRAMES` keyframes from it) and whose place (``place`` =
    (radius m, turn rad) under ``estimate`` ``(K, 3)``) an older held keyframe, travelled ``gap_m`` or
    more before it (``travelled`` ``(K,)``, m), already holds. It rides on the one of those its own loop
    closures joined it to, else the nearest (which keeps it in the solver unless a closure ties the two:
    :func:`shared.slam.riders.take_riders`). So the place keeps its first keyframe, the reference every
    later visit is matched against (module docstring). O(len(indices) x K), vectorised."""
    out: list[tuple[int, int]] = []
    held = np.array(held, dtype=bool)
    currents, candidates = pairs[:, 0], pairs[:, 1]
    for j in indices:
        if not held[j] or not np.any(np.abs(currents - j) <= TIED_KEYFRAMES):
            continue
        older = np.flatnonzero(held[:j] & (travelled[:j] <= travelled[j] - gap_m))
        at = near(estimate, older, estimate[j], *place)
        if not len(at):
            continue
        direct = at[np.isin(at, candidates[currents == j])]
        pool = direct if len(direct) else at
        dist = np.hypot(estimate[pool, 0] - estimate[j, 0], estimate[pool, 1] - estimate[j, 1])
        held[j] = False
        out.append((j, int(pool[int(np.argmin(dist))])))
    return out
