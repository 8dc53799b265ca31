"""Free-space evidence: what later beams pass through leaves the map; real walls, grazing views and
no-return gaps do not."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.pipeline import IcpGate, MergeTolerances, Pipeline, PipelineConfig, WallMap
from shared.pipeline.freespace import HIT, PASS, FreeSpace, FreeSpaceModel, beam_wall_events, supported_runs
from shared.sim.scene import BLACK, MATTE, Scene, Walker, simulate_scene_scan
from shared.types import URG04LX, Pose2D, Scan

P = FreeSpaceModel().packed()


def _box(x0: float, y0: float, x1: float, y1: float) -> list[list[float]]:
    return [[x0, y0, x1, y0], [x1, y0, x1, y1], [x1, y1, x0, y1], [x0, y1, x0, y0]]


def _map_scene(scene: Scene, poses: list[Pose2D], rate_hz: float = 10.0, seed: int = 0) -> Pipeline:
    """Map ``scene`` from ``poses`` (one scan each) with the default mapping stages on exact odometry and
    no pose correction: what is tested is the map update, not pose tracking."""
    rng = np.random.default_rng(seed)
    pipe = Pipeline(PipelineConfig(scan_matching=None), icp_gate=IcpGate(refine_to_map=False))
    for k, pose in enumerate(poses):
        scan, _ = simulate_scene_scan(scene, pose, k / rate_hz, rng)
        pipe.step(scan)
    return pipe


def _far_from(segments: np.ndarray, walls: np.ndarray, tol_m: float) -> list[np.ndarray]:
    """Map segments with a point (ends or middle) farther than ``tol_m`` from every wall in ``walls``."""
    out = []
    for seg in segments:
        pts = np.array([seg[:2], seg[2:], 0.5 * (seg[:2] + seg[2:])])
        d = np.full(3, np.inf)
        for w in walls:
            a, b = w[:2], w[2:]
            ab = b - a
            t = np.clip(((pts - a) @ ab) / (ab @ ab), 0.0, 1.0)
            d = np.minimum(d, np.hypot(*(pts - a - t[:, None] * ab).T))
        if d.max() > tol_m:
            out.append(seg)
    return out


def _covered(segments: np.ndarray, wall: list[float], tol_m: float = 0.1) -> float:
    """Share of ``wall`` (sampled every 5 cm) within ``tol_m`` of some map segment."""
    a, b = np.array(wall[:2]), np.array(wall[2:])
    n = max(int(np.hypot(*(b - a)) / 0.05), 2)
    pts = a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)
    best = np.full(n, np.inf)
    for seg in segments:
        p, q = seg[:2], seg[2:]
        pq = q - p
        t = np.clip(((pts - p) @ pq) / max(pq @ pq, 1e-12), 0.0, 1.0)
        best = np.minimum(best, np.hypot(*(pts - p - t[:, None] * pq).T))
    return float((best <= tol_m).mean())


def test_person_crossing_in_front_leaves_no_wall() -> None:
    room = np.array(_box(-1.0, -2.5, 5.0, 2.5))
    # a person crosses 2 m ahead, twice, then leaves; the robot creeps forward meanwhile
    walker = Walker(np.array([[2.0, -2.2], [2.0, 2.2], [2.2, -2.2]]), 1.0, start_s=0.5, bounce=False)
    scene = Scene(room, "crossing", np.array([[0.0, 0.0], [1.0, 0.0]]), people=(walker,))
    poses = [Pose2D(0.01 * k, 0.0, 0.0) for k in range(140)]
    pipe = _map_scene(scene, poses)
    segments = pipe.walls()[1]
    assert len(segments) >= 3
    assert _far_from(segments, room, 0.15) == []
    for wall in room[[0, 1, 2]]:  # the walls in view stay
        assert _covered(segments, list(wall)) > 0.6


def test_wall_seen_through_is_removed_and_door_opening_cut() -> None:
    back = [4.0, -2.0, 4.0, 2.0]
    sides = [[-1.0, -2.0, 4.0, -2.0], [-1.0, 2.0, 4.0, 2.0]]  # beams past the ends return too
    partition = [2.0, -1.5, 2.0, 1.5]  # gone at 2 s: the back wall shows through it
    wall_lo, door, wall_hi = [1.5, -2.0, 1.5, -0.4], [1.5, -0.4, 1.5, 0.4], [1.5, 0.4, 1.5, 2.0]
    scene_a = Scene(
        np.array([back, *sides, partition]),
        "partition",
        np.array([[0.0, 0.0], [1.0, 0.0]]),
        wall_times=np.array([[-np.inf, np.inf]] * 3 + [[-np.inf, 2.0]]),
    )
    pipe = _map_scene(scene_a, [Pose2D(0.0, 0.0, 0.0)] * 50)
    segs = pipe.walls()[1]
    assert _covered(segs, partition) < 0.05
    assert _covered(segs, back) > 0.9
    # a door leaf in a wall opens: only the opening leaves the map
    scene_b = Scene(
        np.array([back, *sides, wall_lo, door, wall_hi]),
        "door",
        np.array([[0.0, 0.0], [1.0, 0.0]]),
        wall_times=np.array([[-np.inf, np.inf]] * 4 + [[-np.inf, 2.0], [-np.inf, np.inf]]),
    )
    pipe = _map_scene(scene_b, [Pose2D(0.0, 0.0, 0.0)] * 50)
    segs = pipe.walls()[1]
    assert _covered(segs, [1.5, -0.25, 1.5, 0.25]) < 0.05  # the opening (the leaf was 0.8 m)
    assert _covered(segs, [1.5, -1.5, 1.5, -0.6]) > 0.9 and _covered(segs, [1.5, 0.6, 1.5, 1.5]) > 0.9
    assert _covered(segs, [4.0, -0.3, 4.0, 0.3]) > 0.9  # seen through the opening


def test_corridor_walls_seen_at_grazing_angles_stay() -> None:
    corridor = np.array([[-1.0, -1.0, 12.0, -1.0], [-1.0, 1.0, 12.0, 1.0], [12.0, -1.0, 12.0, 1.0]])
    scene = Scene(corridor, "corridor", np.array([[0.0, 0.0], [8.0, 0.0]]))
    poses = [Pose2D(0.04 * k, 0.02 * math.sin(0.1 * k), 0.01 * math.sin(0.07 * k)) for k in range(200)]
    pipe = _map_scene(scene, poses)
    segs = pipe.walls()[1]
    for wall in ([0.0, -1.0, 8.0, -1.0], [0.0, 1.0, 8.0, 1.0]):
        assert _covered(segs, wall) > 0.95
    assert _far_from(segs, corridor, 0.15) == []


def test_no_return_gap_does_not_erase_the_wall_behind() -> None:
    wall = [3.0, -2.0, 3.0, 2.0]
    black = [2.9, -0.8, 2.9, 0.8]  # from 1 s on, a black panel in front absorbs the middle beams
    scene = Scene(
        np.array([wall, black]),
        "black",
        np.array([[0.0, 0.0], [1.0, 0.0]]),
        surface=np.array([MATTE, BLACK]),
        wall_times=np.array([[-np.inf, np.inf], [1.0, np.inf]]),
    )
    pipe = _map_scene(scene, [Pose2D(0.0, 0.0, 0.0)] * 60)
    assert _covered(pipe.walls()[1], [3.0, -0.7, 3.0, 0.7]) > 0.9
    # and directly: scans with no return at all are no evidence
    walls = WallMap(MergeTolerances(min_observations=1))
    walls.add_segments([wall])
    free = FreeSpace()
    blank = Scan.from_geometry(URG04LX, np.full(URG04LX.beam_count, np.nan))
    for _ in range(50):
        assert free.observe(walls, Pose2D(), blank) == []
    assert len(walls.segments()) == 1


def _one_beam(
    origin: tuple[float, float], angle: float, r: float, seg: list[float]
) -> tuple[list[int], list[float]]:
    ev = beam_wall_events(
        origin[0], origin[1], angle, 0.01, np.array([r]), np.array([seg]), np.zeros((1, 2)), P
    )
    return [int(k) for k in ev[:, 2]], ev[:, 1].tolist()


@settings(max_examples=200, deadline=None)
@given(
    st.floats(-5, 5),
    st.floats(-5, 5),
    st.floats(0, 2 * math.pi),
    st.floats(0.5, 4.0),
    st.floats(0.05, 0.95),
    st.floats(math.radians(25), math.radians(155)),
    st.floats(0.3, 4.0),
)
def test_ray_segment_geometry(
    x: float, y: float, phi: float, length: float, frac: float, incidence: float, dist: float
) -> None:
    """A beam aimed at a point of a wall crosses it there: a return at the crossing is a hit, one well
    beyond is a pass-through at the same place along the wall, one well before is no evidence."""
    d = np.array([math.cos(phi), math.sin(phi)])
    a = np.array([x, y])
    seg = [x, y, *(a + length * d)]
    target = a + frac * length * d
    beam = phi + incidence  # angle between beam and wall
    origin = target - dist * np.array([math.cos(beam), math.sin(beam)])
    tol = 3.0 * math.sqrt(
        (0.0125 * max(dist, 1.0)) ** 2 + (0.04**2 + (dist * 0.01) ** 2) / math.sin(incidence) ** 2
    )
    kinds, ts = _one_beam((origin[0], origin[1]), beam, dist, seg)
    assert kinds == [HIT] and abs(ts[0] - frac * length) < 1e-6
    kinds, ts = _one_beam((origin[0], origin[1]), beam, dist + tol + 0.05, seg)
    assert kinds == [PASS] and abs(ts[0] - frac * length) < 1e-6
    if dist - tol - 0.05 > 0.02:
        assert _one_beam((origin[0], origin[1]), beam, dist - tol - 0.05, seg)[0] == []
    # the opposite beam, a grazing one and a beam with no return say nothing
    assert _one_beam((origin[0], origin[1]), beam + math.pi, 10.0, seg)[0] == []
    assert _one_beam((origin[0], origin[1]), beam, math.nan, seg)[0] == []


def test_grazing_beam_is_no_evidence() -> None:
    seg = [0.0, 1.0, 10.0, 1.0]
    for deg in (1.0, 5.0, 10.0):
        assert _one_beam((0.0, 0.0), math.atan2(1.0, 1.0 / math.tan(math.radians(deg))), 20.0, seg)[0] == []
    assert _one_beam((0.0, 0.0), math.radians(30.0), 5.0, seg)[0] == [PASS]


def test_supported_runs() -> None:
    free = np.array([True, False, False, True, False, True, True, False, False, False])
    assert supported_runs(free, 0.1, 0.15) == [(1, 3), (7, 10)]
    assert supported_runs(np.ones(4, bool), 0.1, 0.1) == []


def test_wallmap_cut_shrinks_splits_and_removes() -> None:
    m = WallMap(MergeTolerances(min_observations=1))
    m.add_segments([[0.0, 0.0, 4.0, 0.0], [0.0, 2.0, 2.0, 2.0]])
    wid, other = (int(i) for i in m.ids)
    new = m.cut(wid, [(0.0, 1.0), (3.0, 4.0)])
    assert len(new) == 1 and len(m) == 3
    segs = {int(i): s for i, s in zip(m.ids, m.segments(), strict=True)}
    np.testing.assert_allclose(sorted([segs[wid][0], segs[wid][2]]), [0.0, 1.0], atol=1e-9)
    np.testing.assert_allclose(sorted([segs[new[0]][0], segs[new[0]][2]]), [3.0, 4.0], atol=1e-9)
    # a cut piece still merges consistently with a later collinear segment
    m.add_segments([[0.9, 0.0, 1.6, 0.0]])
    seg = dict(zip(m.ids.tolist(), m.segments(), strict=True))[wid]
    np.testing.assert_allclose([seg[1], seg[3]], [0.0, 0.0], atol=1e-9)
    assert m.cut(other, []) == [] and other in m.removed and len(m) == 2


def _ranges_to(x_m: float) -> np.ndarray:
    """Ranges of a scanner at the origin facing +x whose beams all return from the line x = ``x_m``."""
    angles = URG04LX.angles_rad()
    with np.errstate(divide="ignore"):
        r = np.where(np.cos(angles) > 0.2, x_m / np.cos(angles), np.nan)
    return np.where(r <= URG04LX.range_max_m, r, np.nan)


def test_seen_through_at_once_cut_but_not_after_a_long_drive() -> None:
    """A pass-through 1 m beyond a wall seen a moment ago removes it; after 30 m of driving, the pose may
    have drifted that far relative to it, so the same scans are no evidence."""
    through = Scan.from_geometry(URG04LX, _ranges_to(3.0))
    blank = Scan.from_geometry(URG04LX, np.full(URG04LX.beam_count, np.nan))
    for drive_m in (0.0, 30.0):
        walls = WallMap(MergeTolerances(min_observations=1))
        walls.add_segments([[2.0, -0.5, 2.0, 0.5]])
        free = FreeSpace()
        free.observe(walls, Pose2D(), Scan.from_geometry(URG04LX, _ranges_to(2.0)))  # seen: support
        for k in range(int(drive_m)):  # a drive out and back with the wall out of view
            x = float(k if k < drive_m / 2 else drive_m - k)
            free.observe(walls, Pose2D(-x, 0.0, 0.0), blank)
        for _ in range(20):
            free.observe(walls, Pose2D(), through)
        assert len(walls) == (0 if drive_m == 0.0 else 1)
