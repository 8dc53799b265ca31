"""k-means kernel (paper §3.3, eq. 24): geometry, edge cases, determinism and scikit-learn agreement."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from sklearn.cluster import KMeans as SkKMeans

import shared.kernels
from shared.errors import KernelParameterError
from shared.kernels import REGISTRY, Stage
from shared.kernels.clustering import KMeans
from shared.types import FloatArray


def eq24(points: FloatArray, centroids: FloatArray, labels: np.ndarray) -> float:
    ok = labels >= 0
    return float(((points[ok] - centroids[labels[ok]]) ** 2).sum())


def same_partition(a: np.ndarray, b: np.ndarray) -> bool:
    pairs = set(zip(a.tolist(), b.tolist(), strict=True))
    return len(pairs) == len(set(a.tolist())) == len(set(b.tolist()))


def test_registered() -> None:
    assert shared.kernels.clustering.KMeans is KMeans
    assert REGISTRY.get(Stage.CLUSTERING, "kmeans") is KMeans
    kernel = REGISTRY.create("clustering", "kmeans", {"n_clusters": 4})
    assert isinstance(kernel, KMeans)
    assert kernel.params.n_clusters == 4


def test_defaults_and_validation() -> None:
    p = KMeans().params
    assert (p.n_clusters, p.n_init, p.seed) == (2, 10, 0)
    schema = KMeans.param_schema()["properties"]
    assert schema["tolerance_m"]["unit"] == "m"
    for bad in ({"n_clusters": 0}, {"n_clusters": 1001}, {"n_init": 0}, {"tolerance_m": -1.0}, {"seed": -1}):
        with pytest.raises(KernelParameterError):
            KMeans(bad)


def test_recovers_separated_blobs(blobs: tuple[FloatArray, np.ndarray]) -> None:
    pts, truth = blobs
    res = KMeans(n_clusters=5).apply(pts)
    assert res.n_clusters == 5
    assert same_partition(res.labels, truth)
    for j in range(5):
        np.testing.assert_allclose(res.centroids[j], pts[res.labels == j].mean(axis=0), atol=1e-12)
    assert res.objective == pytest.approx(eq24(pts, res.centroids, res.labels), rel=1e-12)
    assert res.memberships is None


def test_single_cluster_is_the_mean(room_scan: FloatArray) -> None:
    res = KMeans(n_clusters=1).apply(room_scan)
    np.testing.assert_allclose(res.centroids[0], room_scan.mean(axis=0), atol=1e-12)
    assert np.all(res.labels == 0)
    assert res.objective == pytest.approx(((room_scan - room_scan.mean(axis=0)) ** 2).sum(), rel=1e-12)


def test_deterministic_and_frozen(room_scan: FloatArray) -> None:
    ro = room_scan.copy()
    ro.setflags(write=False)
    a = KMeans(n_clusters=4, seed=3).apply(ro)
    b = KMeans(n_clusters=4, seed=3).apply(room_scan.copy())
    np.testing.assert_array_equal(a.centroids, b.centroids)
    np.testing.assert_array_equal(a.labels, b.labels)
    assert a.objective == b.objective
    assert not a.centroids.flags.writeable
    assert not a.labels.flags.writeable
    np.testing.assert_array_equal(ro, room_scan)


def test_non_finite_rows_are_ignored(room_scan: FloatArray) -> None:
    pts = room_scan.copy()
    pts[[0, 10, 20]] = [[np.nan, 1.0], [np.inf, 0.0], [0.0, -np.inf]]
    res = KMeans(n_clusters=3).apply(pts)
    assert res.labels.shape == (pts.shape[0],)
    assert np.all(res.labels[[0, 10, 20]] == -1)
    assert np.all(res.labels[np.isfinite(pts).all(axis=1)] >= 0)
    clean = KMeans(n_clusters=3).apply(np.delete(pts, [0, 10, 20], axis=0))
    np.testing.assert_array_equal(res.centroids, clean.centroids)


def test_empty_one_point_and_all_noise() -> None:
    empty = KMeans(n_clusters=3).apply(np.zeros((0, 2)))
    assert empty.centroids.shape == (0, 2)
    assert empty.labels.shape == (0,)
    assert (empty.objective, empty.n_iter) == (0.0, 0)
    one = KMeans(n_clusters=3).apply([[1.0, 2.0]])
    np.testing.assert_array_equal(one.centroids, [[1.0, 2.0]])
    np.testing.assert_array_equal(one.labels, [0])
    nan = KMeans(n_clusters=3).apply(np.full((4, 2), np.nan))
    assert nan.n_clusters == 0
    np.testing.assert_array_equal(nan.labels, [-1, -1, -1, -1])


def test_fewer_distinct_points_than_clusters() -> None:
    pts = np.array([[0.0, 0.0], [1.0, 1.0], [0.0, 0.0], [1.0, 1.0], [0.0, 0.0]])
    res = KMeans(n_clusters=4).apply(pts)
    assert res.n_clusters == 2
    assert res.objective == 0.0
    assert same_partition(res.labels, np.array([0, 1, 0, 1, 0]))


def test_thousand_points_on_a_line() -> None:
    x = np.linspace(0.0, 10.0, 1000)
    pts = np.column_stack([x, 0.5 * x + 1.0])
    res = KMeans(n_clusters=4).apply(pts)
    assert res.n_clusters == 4
    # the 1-D optimum cuts the segment into four equal pieces
    np.testing.assert_allclose(np.sort(res.centroids[:, 0]), [1.25, 3.75, 6.25, 8.75], atol=0.02)


@pytest.mark.parametrize("k", [2, 3, 4])
def test_online_matches_sklearn(room_scan: FloatArray, k: int) -> None:
    ours = KMeans(n_clusters=k).apply(room_scan)
    ref = SkKMeans(n_clusters=k, n_init=10, random_state=0).fit(room_scan)
    assert ours.objective <= ref.inertia_ * (1.0 + 1e-6)


def test_52_clusters_within_one_percent_of_sklearn(room_batch: FloatArray) -> None:
    ours = KMeans(n_clusters=52, seed=0).apply(room_batch)
    ref = SkKMeans(n_clusters=52, n_init=10, random_state=0).fit(room_batch)
    assert ours.n_clusters == 52
    assert ours.objective <= 1.01 * ref.inertia_
    assert ours.objective == pytest.approx(eq24(room_batch, ours.centroids, ours.labels), rel=1e-9)


points_strategy = arrays(
    np.float64,
    st.tuples(st.integers(0, 60), st.just(2)),
    elements=st.floats(-50.0, 50.0, allow_nan=False, allow_infinity=False).map(lambda v: round(v, 2)),
)


@settings(max_examples=60, deadline=None)
@given(points_strategy, st.integers(1, 8), st.integers(0, 2**32 - 1))
def test_voronoi_and_objective_invariants(points: FloatArray, k: int, seed: int) -> None:
    res = KMeans(n_clusters=k, seed=seed, n_init=2).apply(points)
    distinct = len({tuple(p) for p in points.tolist()})
    assert res.n_clusters == min(k, distinct)
    assert res.labels.shape == (points.shape[0],)
    if points.shape[0] == 0:
        return
    d2 = ((points[:, None, :] - res.centroids[None, :, :]) ** 2).sum(axis=2)
    # every point is labelled with (one of) its nearest centroids
    assert np.all(d2[np.arange(points.shape[0]), res.labels] <= d2.min(axis=1) + 1e-9)
    assert res.objective == pytest.approx(eq24(points, res.centroids, res.labels), rel=1e-9, abs=1e-9)
