"""DBSCAN noise removal (paper §3.2.1) against ``sklearn.cluster.DBSCAN``."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from sklearn.cluster import DBSCAN

from shared.errors import KernelParameterError
from shared.kernels import REGISTRY
from shared.kernels.noise.dbscan import Dbscan, dbscan_core_labels
from shared.sim import RangeNoise, default_path, default_world, simulate_scan
from shared.types import FloatArray, Scan

# sklearn's tree algorithms compare squared distances with eps**2 like we do; its brute-force path
# (chosen by "auto" for tiny inputs) computes distances through a dot-product expansion that can round a
# pair lying exactly at eps either way, so the exact-tie cases below pin algorithm="kd_tree".


def sklearn_core_labels(
    points: FloatArray, eps: float, min_points: int, algorithm: str = "auto"
) -> tuple[np.ndarray, np.ndarray]:
    fit = DBSCAN(eps=eps, min_samples=min_points, algorithm=algorithm).fit(points)
    core = np.zeros(len(points), dtype=bool)
    core[fit.core_sample_indices_] = True
    return core, fit.labels_


def assert_same_as_sklearn(points: FloatArray, eps: float, min_points: int, algorithm: str = "auto") -> None:
    """Same core/border/noise split, same core partition up to relabelling, borders next to their cluster."""
    core, labels = dbscan_core_labels(points, eps, min_points)
    if len(points) == 0:
        assert core.size == 0
        assert labels.size == 0
        return
    sk_core, sk_labels = sklearn_core_labels(points, eps, min_points, algorithm)
    np.testing.assert_array_equal(core, sk_core)
    np.testing.assert_array_equal(labels == -1, sk_labels == -1)
    # the partition of the core points: a bijection between our cluster ids and sklearn's
    pairs = set(zip(labels[core].tolist(), sk_labels[core].tolist(), strict=True))
    assert len(pairs) == len({a for a, _ in pairs}) == len({b for _, b in pairs})
    # every border point carries the cluster of a core point within eps
    for i in np.flatnonzero(~core & (labels >= 0)):
        d2 = ((points - points[i]) ** 2).sum(axis=1)
        assert labels[i] in set(labels[core & (d2 <= eps * eps)].tolist())
    # stronger: we number clusters and pick border clusters exactly as sklearn's expansion order does
    np.testing.assert_array_equal(labels, sk_labels)


def scan_points(seed: int = 1) -> FloatArray:
    rng = np.random.default_rng(seed)
    scan: Scan = simulate_scan(default_world(), default_path(30)[5], rng, RangeNoise(outlier_rate=0.05))
    pts, _ = scan.to_points()
    return pts


def batch_points(seed: int = 2) -> FloatArray:
    """Nine consecutive scans along the default path in the world frame (an offline batch, ~5,000 points)."""
    rng = np.random.default_rng(seed)
    world = default_world()
    out = []
    for pose in default_path(60)[10:19]:
        pts, _ = simulate_scan(world, pose, rng, RangeNoise(outlier_rate=0.05)).to_points()
        out.append(pose.transform_points(pts))
    return np.concatenate(out)


# --- fixed cases -----------------------------------------------------------------------------------


def test_points_exactly_at_eps_are_neighbours() -> None:
    pts = np.array([[0.0, 0.0], [0.05, 0.0], [0.1, 0.0], [0.1, 0.05], [0.5, 0.5]])
    core, labels = dbscan_core_labels(pts, 0.05, 3)
    np.testing.assert_array_equal(core, [False, True, True, False, False])
    np.testing.assert_array_equal(labels, [0, 0, 0, 0, -1])
    assert_same_as_sklearn(pts, 0.05, 3, algorithm="kd_tree")


def test_exact_ties_on_a_dyadic_grid_match_every_sklearn_algorithm() -> None:
    xs, ys = np.meshgrid(np.arange(6) * 0.25, np.arange(3) * 0.25)
    pts = np.column_stack([xs.ravel(), ys.ravel()])
    for algorithm in ("brute", "kd_tree", "ball_tree"):
        for min_points in (2, 3, 4, 5, 6):
            assert_same_as_sklearn(pts, 0.25, min_points, algorithm)


def test_duplicates_count_as_neighbours() -> None:
    pts = np.array([[1.0, 2.0]] * 5 + [[3.0, 3.0]])
    core, labels = dbscan_core_labels(pts, 0.01, 5)
    np.testing.assert_array_equal(core, [True] * 5 + [False])
    np.testing.assert_array_equal(labels, [0] * 5 + [-1])
    core, labels = dbscan_core_labels(pts, 0.01, 6)
    assert not core.any()
    assert (labels == -1).all()
    assert_same_as_sklearn(pts, 0.01, 5)


def test_min_points_one_makes_every_point_a_cluster_seed() -> None:
    pts = np.array([[0.0, 0.0], [10.0, 0.0], [10.01, 0.0]])
    core, labels = dbscan_core_labels(pts, 0.05, 1)
    assert core.all()
    np.testing.assert_array_equal(labels, [0, 1, 1])


def test_border_point_between_two_clusters_takes_the_lower_cluster() -> None:
    left = np.array([[0.0, 0.0], [0.01, 0.0], [0.02, 0.0]])
    right = left + np.array([0.1, 0.0])
    border = np.array([[0.06, 0.0]])  # 0.04 from both inner ends, not core itself
    pts = np.concatenate([right, border, left])
    assert_same_as_sklearn(pts, 0.045, 3, algorithm="kd_tree")
    _, labels = dbscan_core_labels(pts, 0.045, 3)
    assert labels[3] == 0  # the right cluster comes first in input order


def test_far_apart_coordinates() -> None:
    rng = np.random.default_rng(5)
    pts = np.concatenate(
        [
            rng.normal(0, 0.02, (50, 2)),
            rng.normal(0, 0.02, (50, 2)) + 1e5,
            rng.normal(0, 0.02, (50, 2)) - [3e4, 0],
        ]
    )
    assert_same_as_sklearn(pts, 0.03, 4)


def test_scan_and_batch_like_data() -> None:
    scan = scan_points()
    batch = batch_points()
    assert 400 < len(scan) < 700
    assert len(batch) > 4000
    for min_points in (3, 4, 6):
        assert_same_as_sklearn(scan, 0.05, min_points)
    assert_same_as_sklearn(batch, 0.05, 4)
    assert_same_as_sklearn(batch, 0.02, 3)


# --- property tests --------------------------------------------------------------------------------

grid_points = st.lists(st.tuples(st.integers(0, 24), st.integers(0, 24)), min_size=0, max_size=120)


@settings(max_examples=80, deadline=None)
@given(cells=grid_points, eps_steps=st.integers(1, 6), min_points=st.integers(1, 7))
def test_matches_sklearn_on_a_grid_with_ties_and_duplicates(
    cells: list[tuple[int, int]], eps_steps: int, min_points: int
) -> None:
    pts = np.array(cells, dtype=np.float64).reshape(-1, 2) / 32.0  # dyadic: distances and eps are exact
    assert_same_as_sklearn(pts, eps_steps / 32.0, min_points)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 400),
    eps=st.floats(0.005, 0.5),
    min_points=st.integers(1, 10),
    scale=st.floats(0.05, 5.0),
)
def test_matches_sklearn_on_random_clustered_data(
    seed: int, n: int, eps: float, min_points: int, scale: float
) -> None:
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-scale, scale, (max(1, n // 40), 2))
    pts = centres[rng.integers(0, len(centres), n)] + rng.normal(0.0, scale / 20, (n, 2))
    noise = rng.random(n) < 0.1
    pts[noise] = rng.uniform(-scale, scale, (int(noise.sum()), 2))
    assert_same_as_sklearn(pts, eps, min_points)


# --- the kernel --------------------------------------------------------------------------------------


def test_kernel_result_layout_and_registry() -> None:
    assert REGISTRY.get("noise-removal", "dbscan") is Dbscan
    pts = scan_points()
    bad = pts.copy()
    bad[[0, 10]] = [[np.nan, 0.0], [np.inf, 1.0]]
    bad.setflags(write=False)
    kernel = Dbscan(epsilon_m=0.05, min_points=3)
    res = kernel.apply(bad)
    _, labels = dbscan_core_labels(bad, 0.05, 3)
    np.testing.assert_array_equal(res.keep, labels >= 0)
    assert not res.keep[[0, 10]].any()
    np.testing.assert_array_equal(res.points, bad[res.keep])
    np.testing.assert_array_equal(res.labels, labels[res.keep])
    assert set(res.labels.tolist()) == set(range(int(res.labels.max()) + 1))
    assert res.n_added == 0
    assert not (res.keep.flags.writeable)
    assert not (res.points.flags.writeable)
    assert not (res.labels.flags.writeable)


def test_defaults_keep_walls_and_drop_isolated_outliers() -> None:
    rng = np.random.default_rng(0)
    angles = np.deg2rad(-119.5) + np.deg2rad(360 / 1024) * np.arange(682)
    ranges = 3.0 / np.maximum(np.cos(angles), 0.2) + rng.normal(0, 0.01, 682)  # a wall x = 3 m
    wall = np.column_stack([ranges * np.cos(angles), ranges * np.sin(angles)])
    wall = wall[np.abs(wall[:, 1]) < 4.0]
    outliers = rng.uniform(0.3, 2.5, (20, 2)) * [1.0, 0.0] + rng.uniform(-1, 1, (20, 2)) * [0.0, 1.0]
    res = Dbscan().apply(np.concatenate([wall, outliers]))
    assert res.keep[: len(wall)].mean() > 0.95
    assert not res.keep[len(wall) :].any()


def test_empty_and_single_point() -> None:
    for pts in (np.zeros((0, 2)), np.array([[1.0, 1.0]]), np.array([[np.nan, np.nan]])):
        res = Dbscan().apply(pts)
        assert res.keep.shape == (len(pts),)
        assert res.points.shape[0] == int(res.keep.sum())
    assert Dbscan(min_points=1).apply(np.array([[1.0, 1.0]])).keep.all()


@pytest.mark.parametrize("bad", [{"epsilon_m": 0.0}, {"epsilon_m": 11.0}, {"min_points": 0}])
def test_bad_parameters_are_rejected(bad: dict[str, float]) -> None:
    with pytest.raises(KernelParameterError, match=next(iter(bad))):
        Dbscan(bad)


# --- neighbourhoods that follow the beam spacing ----------------------------------------------------


def sklearn_core_labels_per_point(
    points: FloatArray, radius: FloatArray, min_points: int
) -> tuple[np.ndarray, np.ndarray]:
    """scikit-learn's DBSCAN on distances divided by the larger of the two points' radii, eps = 1."""
    d = np.sqrt(((points[:, None, :] - points[None, :, :]) ** 2).sum(axis=2))
    fit = DBSCAN(eps=1.0, min_samples=min_points, metric="precomputed").fit(
        d / np.maximum(radius[:, None], radius[None, :])
    )
    core = np.zeros(len(points), dtype=bool)
    core[fit.core_sample_indices_] = True
    return core, fit.labels_


@pytest.mark.parametrize("seed", range(8))
def test_per_point_radii_match_sklearn_on_scaled_distances(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(20, 250))
    pts = rng.uniform(-2.0, 2.0, (n, 2))
    radius = rng.uniform(0.05, 0.4, n)
    core, labels = dbscan_core_labels(pts, 0.05, 3, radius)
    sk_core, sk_labels = sklearn_core_labels_per_point(pts, radius, 3)
    np.testing.assert_array_equal(core, sk_core)
    np.testing.assert_array_equal(labels, sk_labels)


def test_radii_equal_to_epsilon_are_the_paper_dbscan() -> None:
    pts = batch_points()
    core, labels = dbscan_core_labels(pts, 0.05, 3)
    core_r, labels_r = dbscan_core_labels(pts, 0.05, 3, np.full(len(pts), 0.05))
    np.testing.assert_array_equal(core, core_r)
    np.testing.assert_array_equal(labels, labels_r)


def test_radii_of_the_wrong_shape_are_refused() -> None:
    with pytest.raises(ValueError, match=r"radius_m has shape \(3,\): expected \(4,\)"):
        dbscan_core_labels(np.zeros((4, 2)), 0.05, 3, np.ones(3))


def _one_degree_scan_of_a_wall(distance_m: float) -> tuple[FloatArray, FloatArray]:
    """Returns of a wall ``distance_m`` ahead seen by a 1 deg scanner within +-30 deg, and one lone return
    2 m beside it; with each return's beam spacing (range x 1 deg)."""
    angles = np.radians(np.arange(-30.0, 31.0, 1.0))
    ranges = distance_m / np.cos(angles)
    pts = np.column_stack([ranges * np.cos(angles), ranges * np.sin(angles)])
    lone = np.array([[distance_m - 2.0, distance_m * 0.9]])
    pts = np.vstack([pts, lone])
    return pts, np.hypot(pts[:, 0], pts[:, 1]) * np.radians(1.0)


def test_a_far_wall_of_a_coarse_scanner_is_kept_and_a_lone_return_is_not() -> None:
    pts, spacing = _one_degree_scan_of_a_wall(12.0)  # 21 cm between returns
    kernel = Dbscan()
    paper = kernel.apply(pts)
    assert not paper.keep[:-1].any()  # the paper's 5 cm: every return of the wall is "noise"
    widened = kernel.apply(pts, spacing_m=spacing)
    assert widened.keep[:-1].all()
    assert not widened.keep[-1]
    assert not Dbscan(spacing_factor=0.0).apply(pts, spacing_m=spacing).keep.any()


def test_on_a_urg04lx_the_beam_spacing_changes_nothing() -> None:
    """0.35 deg beams out to the URG-04LX's 5.6 m: 1.4 x the spacing stays below epsilon's 5 cm."""
    pts = scan_points()
    spacing = np.hypot(pts[:, 0], pts[:, 1]) * (2.0 * np.pi / 1024.0)
    kernel = Dbscan()
    a, b = kernel.apply(pts), kernel.apply(pts, spacing_m=spacing)
    np.testing.assert_array_equal(a.keep, b.keep)
    np.testing.assert_array_equal(a.labels, b.labels)
