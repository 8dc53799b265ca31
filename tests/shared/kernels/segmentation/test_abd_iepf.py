"""Tests of the ``abd-iepf`` segmentation kernel (paper §3.1, eq. 13-16)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from shared.errors import KernelParameterError
from shared.kernels import REGISTRY
from shared.kernels.segmentation import AbdIepf
from shared.types import URG04LX, Pose2D, Scan

F = NDArray[np.float64]

#: 4 x 4 m room centred on the origin: walls x0, y0, x1, y1
SQUARE = np.array([[2, -2, 2, 2], [2, 2, -2, 2], [-2, 2, -2, -2], [-2, -2, 2, -2]], dtype=np.float64)


def raycast(walls: F, pose: Pose2D, angles: F) -> F:
    """Range along each beam to the nearest wall (inf when none)."""
    a = angles + pose.theta_rad
    d = np.stack([np.cos(a), np.sin(a)], axis=1)
    p0 = walls[:, :2]
    e = walls[:, 2:] - p0
    w = p0[None] - np.array([pose.x_m, pose.y_m])
    den = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (w[..., 0] * e[None, :, 1] - w[..., 1] * e[None, :, 0]) / den
        u = (w[..., 0] * d[:, None, 1] - w[..., 1] * d[:, None, 0]) / den
    hit = (np.abs(den) > 1e-12) & (t > 0) & (u >= 0) & (u <= 1)
    return np.asarray(np.where(hit, t, np.inf).min(axis=1))


def urg_scan(walls: F, pose: Pose2D | None = None, sigma: float = 0.0, seed: int = 0) -> Scan:
    ranges = raycast(walls, pose or Pose2D(), URG04LX.angles_rad())
    ranges = ranges + np.random.default_rng(seed).normal(0.0, sigma, ranges.size)
    return Scan.from_geometry(URG04LX, ranges)


def fit_line(points: F) -> tuple[F, F]:
    """Centroid and unit direction of the total-least-squares line through ``points``."""
    c = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - c)
    return c, vt[0]


def intersect(c1: F, d1: F, c2: F, d2: F) -> F:
    t = np.linalg.solve(np.stack([d1, -d2], axis=1), c2 - c1)
    return np.asarray(c1 + t[0] * d1)


def reference_labels(scan: Scan, kernel: AbdIepf) -> NDArray[np.intp]:
    """Straightforward recursive re-statement of §3.1 (for cross-checking the compiled kernel)."""
    p = kernel.params
    pts, idx = scan.to_points()
    r = scan.ranges_m[idx]
    phi = scan.angles_rad[idx]
    lam = math.radians(p.lambda_deg)
    labels = np.full(len(pts), -1, dtype=np.intp)
    next_label = 0

    def joins(a: int, b: int) -> bool:
        dphi = abs(phi[b] - phi[a])
        if lam <= dphi:
            return False
        d_th = r[a] * math.sin(dphi) / math.sin(lam - dphi) + 3 * p.sigma_r_m
        return bool(math.hypot(*(pts[b] - pts[a])) < d_th)

    def straight(members: list[int]) -> tuple[bool, int]:
        q = pts[members]
        if len(q) < 3:
            return True, -1
        u = q[-1] - q[0]
        norm = math.hypot(*u)
        if norm > 0:
            d = np.abs(u[0] * (q[:, 1] - q[0, 1]) - u[1] * (q[:, 0] - q[0, 0])) / norm
        else:
            d = np.hypot(*(q - q[0]).T)
        d_t = min(max(3 * p.sigma_r0_m + p.epsilon_a * (r[members].mean() - p.r0_m), 3 * p.sigma_r0_m),
                  p.split_max_m)
        k = int(np.argmax(d[1:-1])) + 1
        return (False, k) if d[k] > d_t else (True, -1)

    def split(members: list[int]) -> list[list[int]]:
        ok, k = straight(members)
        return [members] if ok else split(members[: k + 1]) + split(members[k + 1 :])

    def merge(pieces: list[list[int]]) -> list[list[int]]:
        merged: list[list[int]] = []
        for piece in pieces:
            if merged and straight(merged[-1] + piece)[0]:
                merged[-1] = merged[-1] + piece
            else:
                merged.append(piece)
        return merged

    def refine(chunk: list[int], pieces: list[list[int]]) -> list[list[int]]:
        q = pts[chunk] - pts[chunk[0]]
        cols = [q[:, 0], q[:, 1], q[:, 0] ** 2, q[:, 1] ** 2, q[:, 0] * q[:, 1]]
        sums = np.concatenate([np.zeros((5, 1)), np.cumsum(np.array(cols), axis=1)], axis=1)
        pos = {m: i for i, m in enumerate(chunk)}

        def sse(a: int, b: int) -> float:
            n = b - a + 1
            sx, sy, sxx, syy, sxy = sums[:, b + 1] - sums[:, a]
            cxx, cyy, cxy = sxx - sx * sx / n, syy - sy * sy / n, sxy - sx * sy / n
            return float(max(0.5 * (cxx + cyy) - math.sqrt((0.5 * (cxx - cyy)) ** 2 + cxy**2), 0.0))

        for i in range(len(pieces) - 1):
            union = pieces[i] + pieces[i + 1]
            if len(union) < 4 or straight(union)[0]:
                continue
            s0, e0 = pos[union[0]], pos[union[-1]]
            costs = [sse(s0, b) + sse(b + 1, e0) for b in range(s0 + 1, e0 - 1)]
            b = s0 + 1 + int(np.argmin(costs))
            pieces[i], pieces[i + 1] = chunk[s0 : b + 1], chunk[b + 1 : e0 + 1]
        return pieces

    def segment(chunk: list[int]) -> None:
        nonlocal next_label
        if len(chunk) < p.min_points:
            return
        pieces = merge(split(chunk))
        if len(pieces) > 1:
            pieces = merge(refine(chunk, pieces))
        for piece in pieces:
            if len(piece) >= p.min_points:
                labels[piece] = next_label
                next_label += 1

    if len(pts) == 0:
        return labels
    chunk = [0]
    j = 1
    while j < len(pts):
        nxt = next((k for k in range(j, min(len(pts), j + p.max_skip + 1)) if joins(chunk[-1], k)), -1)
        if nxt >= 0:
            chunk.append(nxt)
            j = nxt + 1
        else:
            segment(chunk)
            chunk = [j]
            j += 1
    segment(chunk)
    return labels


def test_registered() -> None:
    assert REGISTRY.get("segmentation", "abd-iepf") is AbdIepf
    kernel = REGISTRY.create("segmentation", "abd-iepf", {"lambda_deg": 12.0})
    assert isinstance(kernel, AbdIepf)
    assert kernel.params.lambda_deg == 12.0


@pytest.mark.parametrize(
    "bad",
    [{"lambda_deg": 0.0}, {"lambda_deg": 90.0}, {"min_points": 0}, {"sigma_r0_m": 0.0}, {"max_skip": -1},
     {"no_such": 1}],
)
def test_invalid_parameters_are_refused(bad: dict[str, float]) -> None:
    with pytest.raises(KernelParameterError):
        AbdIepf(bad)


@pytest.mark.parametrize("sigma", [0.0, 0.01])
def test_square_room_one_segment_per_wall_and_corners_split(sigma: float) -> None:
    # from the centre the URG (+-120 deg) sees the right, front and left walls; the back wall is behind it
    scan = urg_scan(SQUARE, sigma=sigma, seed=3)
    seg = AbdIepf().apply(scan)
    assert seg.n_segments == 3
    assert np.all(seg.labels >= 0)
    walls = [SQUARE[3], SQUARE[0], SQUARE[1]]  # y = -2, x = 2, y = 2 in scan order
    for label, wall in enumerate(walls):
        pts = seg.points[seg.labels == label]
        axis = 1 if wall[1] == wall[3] else 0
        assert np.all(np.abs(pts[:, axis] - wall[axis]) < 0.05 + 4 * sigma)
    fitted = [fit_line(seg.points[seg.labels == k]) for k in range(3)]
    for k, truth in enumerate([(2.0, -2.0), (2.0, 2.0)]):
        corner = intersect(*fitted[k], *fitted[k + 1])
        assert np.hypot(*(corner - truth)) < 0.02
        # the split falls at the corner: the last point of one piece and the first of the next are beside it
        last = seg.points[seg.labels == k][-1]
        first = seg.points[seg.labels == k + 1][0]
        assert np.hypot(*(last - truth)) < 0.05 + 3 * sigma
        assert np.hypot(*(first - truth)) < 0.05 + 3 * sigma


def test_noisy_square_room_is_stable_over_seeds() -> None:
    kernel = AbdIepf()
    counts = [kernel.apply(urg_scan(SQUARE, sigma=0.01, seed=s)).n_segments for s in range(20)]
    assert counts == [3] * 20


def test_door_gap_breaks() -> None:
    # front wall x = 2 with a 0.8 m door; a corridor wall at x = 4 behind it
    walls = np.array([[2, -2, 2, -0.4], [2, 0.4, 2, 2], [4, -0.4, 4, 0.4], [2, -0.4, 4, -0.4],
                      [2, 0.4, 4, 0.4]], dtype=np.float64)
    scan = Scan.from_geometry(URG04LX, raycast(walls, Pose2D(), URG04LX.angles_rad()))
    seg = AbdIepf().apply(scan)
    pts = seg.points
    near = np.abs(pts[:, 0] - 2.0) < 1e-6
    far = pts[:, 0] > 2.0 + 1e-6
    right = near & (pts[:, 1] < 0)
    left = near & (pts[:, 1] > 0)
    # the wall pieces either side of the door are different segments, and nothing beyond the door joins them
    right_labels = set(seg.labels[right].tolist())
    left_labels = set(seg.labels[left].tolist())
    far_labels = set(seg.labels[far].tolist()) - {-1}
    assert len(right_labels) == 1
    assert len(left_labels) == 1
    assert right_labels.isdisjoint(left_labels)
    assert far_labels.isdisjoint(right_labels | left_labels)


def test_gap_of_invalid_beams() -> None:
    ranges = np.full(URG04LX.beam_count, 2.0)  # a circle: consecutive points are well within D_th
    wide = ranges.copy()
    wide[300:340] = np.nan  # 40 beams ~ 14 deg > lambda: always a break (eq. 15 guard)
    seg = AbdIepf(split_max_m=10.0, epsilon_a=1.0).apply(Scan.from_geometry(URG04LX, wide))
    before = seg.labels[seg.beam_index == 299][0]
    after = seg.labels[seg.beam_index == 340][0]
    assert before >= 0
    assert after == before + 1
    narrow = ranges.copy()
    narrow[300:303] = np.inf  # 3 dropped beams: the wider dphi keeps the circle together
    seg = AbdIepf(split_max_m=10.0, epsilon_a=1.0).apply(Scan.from_geometry(URG04LX, narrow))
    assert seg.labels[seg.beam_index == 299][0] == seg.labels[seg.beam_index == 303][0]


def test_noise_free_straight_wall_stays_one_segment() -> None:
    # a thousand points on one line: wall x = 1.5 seen over +-40 deg
    angles = np.linspace(-math.radians(40), math.radians(40), 1000)
    ranges = 1.5 / np.cos(angles)
    scan = Scan(0.0, float(angles[0]), float(angles[1] - angles[0]), 0.02, 5.6, ranges)
    seg = AbdIepf().apply(scan)
    assert seg.n_segments == 1
    assert np.all(seg.labels == 0)


def test_isolated_outliers_break_plain_abd_and_are_skipped_with_max_skip() -> None:
    scan_clean = urg_scan(SQUARE)
    ranges = np.array(scan_clean.ranges_m)
    front = np.flatnonzero(np.abs(URG04LX.angles_rad()) < math.radians(30))
    bad = front[::40]
    ranges[bad] *= 0.5  # short spurious returns in the middle of the front wall
    scan = Scan.from_geometry(URG04LX, ranges)
    plain = AbdIepf(max_skip=0).apply(scan)
    assert plain.n_segments > 3
    skipping = AbdIepf(max_skip=1).apply(scan)
    assert skipping.n_segments == 3
    assert np.all(skipping.labels[np.isin(skipping.beam_index, bad)] == -1)
    assert np.array_equal(skipping.labels, reference_labels(scan, AbdIepf(max_skip=1)))


def test_short_pieces_get_minus_one() -> None:
    ranges = np.full(URG04LX.beam_count, np.nan)
    ranges[100:103] = 1.0  # three returns: fewer than min_points
    ranges[200:260] = 1.0
    seg = AbdIepf(min_points=5).apply(Scan.from_geometry(URG04LX, ranges))
    assert np.all(seg.labels[seg.beam_index < 150] == -1)
    assert np.all(seg.labels[seg.beam_index >= 200] == 0)
    assert AbdIepf(min_points=3).apply(Scan.from_geometry(URG04LX, ranges)).n_segments == 2


def test_empty_and_single_point_scans() -> None:
    empty = AbdIepf().apply(Scan.from_geometry(URG04LX, np.full(URG04LX.beam_count, np.nan)))
    assert empty.points.shape == (0, 2)
    assert empty.labels.shape == (0,)
    assert empty.beam_index.shape == (0,)
    assert empty.n_segments == 0
    ranges = np.full(URG04LX.beam_count, np.inf)
    ranges[10] = 1.0
    one = AbdIepf().apply(Scan.from_geometry(URG04LX, ranges))
    assert one.labels.tolist() == [-1]
    assert one.beam_index.tolist() == [10]
    assert AbdIepf(min_points=1).apply(Scan.from_geometry(URG04LX, ranges)).labels.tolist() == [0]


def test_duplicate_points() -> None:
    # beams so close that every point is the same float: one segment via the closed-chord branch
    scan = Scan(0.0, 0.5, 1e-18, 0.02, 5.6, np.full(50, 2.0))
    pts, _ = scan.to_points()
    assert np.all(pts == pts[0])
    seg = AbdIepf().apply(scan)
    assert seg.labels.tolist() == [0] * 50


def test_result_matches_scan_points_and_is_read_only() -> None:
    scan = urg_scan(SQUARE, sigma=0.01)
    seg = AbdIepf().apply(scan)
    pts, idx = scan.to_points()
    assert np.array_equal(seg.points, pts)
    assert np.array_equal(seg.beam_index, idx)
    for arr in (seg.points, seg.beam_index, seg.labels):
        assert not arr.flags.writeable
    assert seg.labels.dtype == np.intp
    again = AbdIepf().apply(scan)
    assert np.array_equal(again.labels, seg.labels)


@st.composite
def random_scans(draw: st.DrawFn) -> Scan:
    """Piecewise scans: runs of walls at random ranges and slopes, with gaps, jumps and spikes."""
    n = draw(st.integers(0, 400))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    ranges = np.empty(n)
    i = 0
    while i < n:
        run = int(rng.integers(1, 80))
        base = rng.uniform(0.1, 5.5)
        slope = rng.normal(0.0, 0.02)
        ranges[i : i + run] = base + slope * np.arange(min(run, n - i)) + rng.normal(0, 0.01, min(run, n - i))
        i += run
    ranges[rng.random(n) < 0.05] = np.nan
    spikes = rng.random(n) < 0.03
    ranges[spikes] = rng.uniform(0.05, 5.5, int(spikes.sum()))
    return Scan(0.0, -2.0, math.radians(360 / 1024), 0.02, 5.6, ranges)


@settings(max_examples=60, deadline=None)
@given(
    scan=random_scans(),
    min_points=st.integers(1, 12),
    max_skip=st.integers(0, 3),
    lambda_deg=st.floats(0.5, 30.0),
    split_max_m=st.floats(0.01, 0.3),
)
def test_properties_and_agreement_with_reference(
    scan: Scan, min_points: int, max_skip: int, lambda_deg: float, split_max_m: float
) -> None:
    kernel = AbdIepf(min_points=min_points, max_skip=max_skip, lambda_deg=lambda_deg, split_max_m=split_max_m)
    seg = kernel.apply(scan)
    labels = seg.labels
    assert labels.shape == (seg.points.shape[0],)
    good = labels[labels >= 0]
    assert np.all(np.diff(good) >= 0)  # monotone along the scan
    if good.size:
        assert np.array_equal(np.unique(good), np.arange(good.max() + 1))  # 0..S-1, none missing
        assert np.bincount(good).min() >= min_points
    assert np.array_equal(labels, reference_labels(scan, kernel))
