"""Map merging: collinear, overlapping pieces from successive steps become single walls."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.pipeline import MergeTolerances, WallMap

ALL = MergeTolerances(min_observations=1)


def test_overlapping_collinear_pieces_fuse() -> None:
    m = WallMap(ALL)
    m.add_segments([[0.0, 0.0, 2.0, 0.0], [1.5, 0.01, 4.0, 0.01], [3.9, -0.01, 6.0, 0.0]])
    segs = m.segments()
    assert len(segs) == 1
    x = sorted([segs[0, 0], segs[0, 2]])
    assert abs(x[0] - 0.0) < 0.02 and abs(x[1] - 6.0) < 0.02
    assert np.all(np.abs(segs[0, [1, 3]]) < 0.02)


def test_small_gap_bridged_large_gap_not() -> None:
    m = WallMap(ALL)
    m.add_segments(np.array([[0, 0, 1, 0], [1.2, 0, 2, 0]], dtype=float))  # 20 cm gap <= 30 cm
    assert len(m) == 1
    m.add_segments([[3.0, 0, 4, 0]])  # 1 m gap
    assert len(m) == 2


def test_parallel_offset_and_crossing_walls_stay_apart() -> None:
    m = WallMap(ALL)
    m.add_segments(np.array([[0, 0, 2, 0], [0, 0.3, 2, 0.3], [1, -1, 1, 1]], dtype=float))
    assert len(m) == 3


def test_angle_tolerance() -> None:
    m = WallMap(ALL)
    m.add_segments([[0, 0, 2, 0]])
    tilt = math.radians(10)
    m.add_segments([[1, 0, 1 + 2 * math.cos(tilt), 2 * math.sin(tilt)]])
    assert len(m) == 2


def test_a_short_noisy_piece_on_a_wall_joins_it_instead_of_crossing_it() -> None:
    m = WallMap(ALL)
    m.add_segments([[0, 0, 4, 0]])
    tilt = math.radians(20)  # a 0.3 m piece whose noisy fit came out 20 degrees off (ends within 5.2 cm)
    m.add_segments(
        [
            [
                2 - 0.15 * math.cos(tilt),
                -0.15 * math.sin(tilt),
                2 + 0.15 * math.cos(tilt),
                0.15 * math.sin(tilt),
            ]
        ]
    )
    assert len(m) == 1
    (seg,) = m.segments()
    assert abs(seg[1]) < 0.01 and abs(seg[3]) < 0.01  # the wall stays where it was
    m.add_segments([[2, 0.05, 2, 0.35]])  # a short piece of a perpendicular wall touching it: not the wall
    assert len(m) == 2


def test_ids_are_stable_and_older_id_survives() -> None:
    m = WallMap(ALL)
    m.add_segments([[0, 0, 1, 0], [5, 0, 6, 0]])
    assert list(m.ids) == [0, 1]
    m.add_segments([[0.9, 0, 5.1, 0]])  # bridges both
    assert list(m.ids) == [0]
    assert sorted(m.removed) == [1, 2]


def test_walls_need_evidence() -> None:
    m = WallMap(MergeTolerances(min_observations=3))
    m.add_segments([[0, 0, 2, 0]])
    m.add_segments([[5, 5, 5.5, 5.2]])  # clutter, seen once
    assert len(m.segments()) == 0
    m.add_segments([[0.1, 0.01, 2.1, 0.01], [0.05, -0.01, 1.9, 0.0]])
    assert len(m.segments()) == 1 and list(m.ids) == [0]


def test_short_and_non_finite_segments_ignored() -> None:
    m = WallMap(ALL)
    m.add_segments([[0, 0, 0.01, 0], [np.nan, 0, 1, 1]])
    assert len(m) == 0


@settings(max_examples=50)
@given(
    st.floats(-10, 10),
    st.floats(-10, 10),
    st.floats(0, math.pi),
    st.integers(2, 12),
    st.randoms(use_true_random=False),
)
def test_pieces_of_one_wall_fuse_in_any_order(x: float, y: float, angle: float, n: int, rnd: object) -> None:
    """A 6 m wall cut into overlapping pieces fuses into one wall, whatever the insertion order."""
    d = np.array([math.cos(angle), math.sin(angle)])
    starts = np.linspace(0.0, 5.0, n)
    ends = np.minimum(starts + 5.0 / (n - 1) + 0.1, 6.0)
    ends[-1] = 6.0
    origin = np.array([x, y])
    pieces = [np.concatenate([origin + d * s, origin + d * e]) for s, e in zip(starts, ends, strict=True)]
    order = list(range(n))
    rnd.shuffle(order)  # type: ignore[attr-defined]
    m = WallMap(ALL)
    m.add_segments(np.array([pieces[i] for i in order]))
    assert len(m) == 1
    seg = m.segments()[0]
    assert abs(math.hypot(seg[2] - seg[0], seg[3] - seg[1]) - 6.0) < 1e-6


def test_a_wall_cut_and_fused_back_many_times_stays_shown() -> None:
    # a doorway seen open from the corridor: free space cuts the wall there every scan, and the next
    # scan's segment across the gap fuses the two pieces again (each carrying the wall's count); the
    # count doubled each time and, after 63 rounds, wrapped round int64 and hid the wall
    m = WallMap(MergeTolerances(min_observations=3))
    for _ in range(3):
        m.add_segments([[0.0, 0.0, 6.0, 0.0]])
    (wid,) = m.ids
    for _ in range(100):
        pieces = m.cut(int(wid), [(0.0, 2.9), (3.1, 6.0)])
        assert len(pieces) == 1 and len(m.segments()) == 2
        m.add_segments([[2.5, 0.0, 3.5, 0.0]])  # bridges the 0.2 m gap: one wall again
        assert list(m.ids) == [wid]
    assert np.allclose(m.segments(), [[0.0, 0.0, 6.0, 0.0]], atol=1e-6)


def test_a_noisy_piece_of_a_known_wall_is_explained_a_precise_crossing_is_not() -> None:
    m = WallMap(ALL)
    m.add_segments([[0.0, 0.0, 2.0, 0.0]], viewpoint=(1.0, 1.0))
    tilt = math.radians(15.0)
    piece = [0.8, -0.05, 0.8 + 0.4 * math.cos(tilt), -0.05 + 0.4 * math.sin(tilt)]
    far = [0.8, 0.3, 1.2, 0.3]  # parallel, 30 cm in front: another surface
    band = [0.12, 0.12]
    seen_from_front = m.explained([piece, far], [0.1, 0.1], band, viewpoint=(1.0, 1.0))
    assert seen_from_front.tolist() == [True, False]
    # the same piece known to 1 degree is a real crossing; seen from behind it is the wall's other face
    assert not m.explained([piece], [0.02], band[:1], viewpoint=(1.0, 1.0))[0]
    assert not m.explained([piece], [0.1], band[:1], viewpoint=(1.0, -1.0))[0]
    assert m.explained(np.zeros((0, 4)), [], []).shape == (0,)


def test_a_piece_that_may_not_create_joins_a_wall_or_is_dropped() -> None:
    m = WallMap(ALL)
    m.add_segments([[0.0, 0.0, 2.0, 0.0]])
    m.add_segments([[1.5, 0.01, 2.5, 0.01], [0.0, 3.0, 1.0, 3.0]], may_create=[False, False])
    assert len(m) == 1  # the first joined the wall, the second started nothing
    assert np.allclose(m.segments()[0, [0, 2]], [0.0, 2.5], atol=0.01)
    m.add_segments([[0.0, 3.0, 1.0, 3.0]])  # allowed: a wall of its own (the dropped piece's id was
    assert sorted(m.ids.tolist()) == [0, 2]  # never shown, so it is given again)


def _reference_explained(
    m: WallMap, segs: np.ndarray, sd: np.ndarray, band: np.ndarray, viewpoint: tuple[float, float] | None
) -> np.ndarray:
    """WallMap.explained's test written out over all (segment, wall) pairs with numpy (the vectorised form
    the compiled loop replaced)."""
    n = len(m.all_walls()[0])
    if n == 0:
        return np.zeros(len(segs), dtype=bool)
    # the map's own line parameters (centre, unit direction, span along it)
    c, d, lo, hi = m._c[:n], m._d[:n], m._lo[:n], m._hi[:n]
    nrm = np.column_stack([-d[:, 1], d[:, 0]])
    a, b = segs[:, None, :2] - c[None], segs[:, None, 2:] - c[None]
    off = np.maximum(np.abs((a * nrm[None]).sum(2)), np.abs((b * nrm[None]).sum(2)))
    ta, tb = (a * d[None]).sum(2), (b * d[None]).sum(2)
    overlap = (np.maximum(ta, tb) > lo[None]) & (np.minimum(ta, tb) < hi[None])
    u = segs[:, 2:] - segs[:, :2]
    u = u / np.maximum(np.hypot(u[:, 0], u[:, 1]), 1e-12)[:, None]
    if viewpoint is None:
        cos = np.abs(u @ d.T)
    else:
        mid = 0.5 * (segs[:, :2] + segs[:, 2:])
        left = u[:, 0] * (viewpoint[1] - mid[:, 1]) - u[:, 1] * (viewpoint[0] - mid[:, 0]) >= 0.0
        cos = np.where(left, 1.0, -1.0)[:, None] * (u @ d.T)
    tilt = np.arccos(np.clip(cos, -1.0, 1.0))
    ok = overlap & (off <= band[:, None]) & (tilt <= 3.0 * sd[:, None]) & (sd[:, None] > 0.0)
    return np.asarray(ok.any(axis=1))


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.booleans())
def test_explained_agrees_with_a_numpy_reference(seed: int, with_viewpoint: bool) -> None:
    rng = np.random.default_rng(seed)
    m = WallMap()
    m.add_segments(rng.uniform(-5.0, 5.0, (int(rng.integers(1, 30)), 4)), observations=3)
    _, walls = m.all_walls()
    segs = rng.uniform(-5.0, 5.0, (30, 4))
    if len(walls):  # noisy copies of mapped walls: the cases near the test's edges
        segs[:20] = walls[rng.integers(0, len(walls), 20)] + rng.normal(0.0, 0.03, (20, 4))
    sd = rng.uniform(0.0, 0.1, 30)
    sd[:3] = 0.0
    band = rng.uniform(0.02, 0.2, 30)
    viewpoint = (float(rng.uniform(-5, 5)), float(rng.uniform(-5, 5))) if with_viewpoint else None
    got = m.explained(segs, sd, band, viewpoint=viewpoint)
    want = _reference_explained(m, segs, sd, band, viewpoint)
    np.testing.assert_array_equal(got, want)
