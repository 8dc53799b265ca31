"""The scenario suite: kinds of world, driving patterns and odometry errors, simulated into runs with
ground truth (walls at the end of the run, true poses, and which parts of the walls the laser saw).

A case is ``(kind, seed)``: the seed draws the world's sizes and positions, the odometry's errors and the
range noise from separate streams, so the same world can be driven with another odometry model and scan
the same. Each kind has a default odometry model and driving pattern; both can be overridden.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from shared.errors import InvalidInputError
from shared.odometry import MINES_ROVER, DiffDrive
from shared.sim.odometry_errors import ODOMETRY_MODELS, odometry_from_truth
from shared.sim.path import plan_path
from shared.sim.run import SimRun
from shared.sim.scans import RangeNoise
from shared.sim.scene import Hits, Scene, simulate_scene_scan
from shared.sim.world import World
from shared.sim.worlds import dynamic, static
from shared.types import URG04LX, BeamGeometry, FloatArray

__all__ = [
    "DRIVES",
    "KINDS",
    "QUICK_KINDS",
    "CaseRun",
    "WorldKind",
    "build_scene",
    "drive_knots",
    "simulate_case",
]

#: Driving patterns: one pass along the path, out and back, or ``laps`` times (a closed path is driven
#: round; an open one out and back each lap).
DRIVES = ("single", "out-back", "laps")

_CELL_M = 0.05  # resolution of "which part of a wall was seen"
_BRIDGE_M = 0.25  # unseen gaps up to this long between seen parts count as seen (sparse beams)
_MIN_PIECE_M = 0.10


@dataclass(frozen=True, slots=True)
class WorldKind:
    """A kind of world: its builder, default odometry model and driving pattern."""

    name: str
    build: Callable[[np.random.Generator], Scene]
    odometry: str
    drive: str

    @property
    def summary(self) -> str:
        """The builder's one-line description."""
        return " ".join((self.build.__doc__ or self.name).strip().split("\n\n")[0].split())


_KIND_LIST = (
    WorldKind("corridor-long", static.corridor_long, "slip", "single"),
    WorldKind("corridor-doors", static.corridor_doors, "worn", "out-back"),
    WorldKind("office-l", static.office_l, "slip", "single"),
    WorldKind("hall-pillars", static.hall_pillars, "bursts", "single"),
    WorldKind("lab-clutter", static.lab_clutter, "slip", "single"),
    WorldKind("loop-block", static.loop_block, "worn", "laps"),
    WorldKind("glass-black", static.glass_black, "slip", "single"),
    WorldKind("mixed-edges", static.mixed_edges, "slip", "single"),
    WorldKind("people-along", dynamic.people_along, "slip", "single"),
    WorldKind("people-across", dynamic.people_across, "slip", "single"),
    WorldKind("door-opens", dynamic.door_opens, "slip", "out-back"),
    WorldKind("furniture-moved", dynamic.furniture_moved, "bursts", "out-back"),
)
#: The kinds by name, in the suite's order.
KINDS: dict[str, WorldKind] = {k.name: k for k in _KIND_LIST}
#: The kinds of ``--quick``: a corridor beyond range, people crossing, surfaces with no return.
QUICK_KINDS = ("corridor-long", "people-across", "glass-black")


@dataclass(frozen=True, slots=True)
class CaseRun:
    """One simulated case: the run (its ``world`` is the ground truth at the end), the scene it came from,
    the seen parts of the true walls ``seen_walls`` ``(S, 4)`` and how many true walls were seen."""

    kind: str
    seed: int
    odometry: str
    drive: str
    scene: Scene
    run: SimRun
    seen_walls: FloatArray
    walls_seen: int

    @property
    def truth(self) -> World:
        """The true walls at the end of the run."""
        return self.run.world


def _kind(name: str) -> WorldKind:
    if name not in KINDS:
        raise InvalidInputError(f"unknown world kind {name!r}: expected one of {', '.join(KINDS)}")
    return KINDS[name]


def _streams(kind: str, seed: int) -> list[np.random.SeedSequence]:
    if seed < 0:
        raise InvalidInputError(f"seed = {seed}: expected a non-negative integer")
    return np.random.SeedSequence([zlib.crc32(kind.encode()), seed]).spawn(3)


def build_scene(kind: str, seed: int) -> Scene:
    """The world of kind ``kind`` drawn with ``seed`` (deterministic)."""
    return _kind(kind).build(np.random.default_rng(_streams(kind, seed)[0]))


def drive_knots(knots: FloatArray, drive: str, laps: int = 2) -> FloatArray:
    """The knots the robot drives for pattern ``drive`` (one of :data:`DRIVES`)."""
    k = np.asarray(knots, dtype=np.float64)
    back = np.vstack([k, k[-2::-1]])
    if drive == "single":
        return k
    if drive == "out-back":
        return back
    if drive == "laps":
        if laps < 1:
            raise InvalidInputError(f"laps = {laps}: expected at least 1")
        closed = bool(np.allclose(k[0], k[-1]))
        lap = k[1:] if closed else back[1:]
        return np.vstack([k[:1], *([lap] * laps)])
    raise InvalidInputError(f"unknown drive {drive!r}: expected one of {', '.join(DRIVES)}")


def _seen_pieces(
    scene: Scene, truth_idx: np.ndarray, hits: list[Hits], geometry: BeamGeometry
) -> tuple[FloatArray, int]:
    """The seen parts of the truth walls and how many walls were seen (see the module docstring)."""
    wall = np.concatenate([h.wall for h in hits])
    u = np.concatenate([h.u for h in hits])
    rng = np.concatenate([h.range_m for h in hits])
    ok = (wall >= 0) & (rng >= geometry.range_min_m) & (rng <= geometry.range_max_m)
    wall, u = wall[ok], u[ok]
    pieces: list[list[float]] = []
    count = 0
    bridge = round(_BRIDGE_M / _CELL_M)
    for i in truth_idx.tolist():
        w = scene.walls[i]
        length = float(np.hypot(w[2] - w[0], w[3] - w[1]))
        cells = max(1, int(np.ceil(length / _CELL_M)))
        seen = np.zeros(cells, dtype=bool)
        seen[np.clip((u[wall == i] * cells).astype(int), 0, cells - 1)] = True
        idx = np.flatnonzero(seen)
        if len(idx) == 0:
            continue
        runs = np.split(idx, np.flatnonzero(np.diff(idx) > bridge + 1) + 1)
        total = 0.0
        for r in runs:
            a, b = r[0] / cells, min(1.0, (r[-1] + 1) / cells)
            if (b - a) * length < min(_MIN_PIECE_M, 0.5 * length):
                continue
            total += (b - a) * length
            p0, p1 = w[:2] + a * (w[2:] - w[:2]), w[:2] + b * (w[2:] - w[:2])
            pieces.append([*p0.tolist(), *p1.tolist()])
        count += int(total >= min(0.2, 0.5 * length))
    return np.array(pieces, dtype=np.float64).reshape(-1, 4), count


def simulate_case(
    kind: str,
    seed: int,
    *,
    odometry: str | None = None,
    drive: str | None = None,
    laps: int = 2,
    max_scans: int | None = None,
    noise: RangeNoise | None = None,
    robot: DiffDrive = MINES_ROVER,
    geometry: BeamGeometry = URG04LX,
    rate_hz: float = 10.0,
) -> CaseRun:
    """Simulate case ``(kind, seed)`` at 10 Hz and 0.4 m/s (``max_scans`` cuts it short).

    O(N x beams x walls)."""
    spec = _kind(kind)
    odo_name, drive_name = odometry or spec.odometry, drive or spec.drive
    if odo_name not in ODOMETRY_MODELS:
        raise InvalidInputError(
            f"unknown odometry model {odo_name!r}: expected one of {', '.join(ODOMETRY_MODELS)}"
        )
    _, odo_seq, scan_seq = _streams(kind, seed)
    scene = build_scene(kind, seed)
    true_poses = plan_path(drive_knots(scene.knots, drive_name, laps), rate_hz=rate_hz)
    if max_scans is not None:
        if max_scans < 2:
            raise InvalidInputError(f"max_scans = {max_scans}: expected at least 2")
        true_poses = true_poses[:max_scans]
    odo_rng = np.random.default_rng(odo_seq)
    ticks, odo = odometry_from_truth(true_poses, robot, ODOMETRY_MODELS[odo_name], odo_rng, rate_hz)
    scan_rng = np.random.default_rng(scan_seq)
    scans, hits = [], []
    for i, (pose, o) in enumerate(zip(true_poses, odo, strict=True)):
        scan, hit = simulate_scene_scan(
            scene, robot.laser_pose(pose), i / rate_hz, scan_rng, noise, geometry, odometry=o
        )
        scans.append(scan)
        hits.append(hit)
    truth, truth_idx = scene.truth((len(true_poses) - 1) / rate_hz)
    seen, count = _seen_pieces(scene, truth_idx, hits, geometry)
    run = SimRun(truth, robot, tuple(scans), tuple(true_poses), tuple(odo), ticks, rate_hz)
    return CaseRun(kind, seed, odo_name, drive_name, scene, run, seen, count)
