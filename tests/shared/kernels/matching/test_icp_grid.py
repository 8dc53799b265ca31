"""The grid nearest-neighbour search behind ``icp`` against :class:`scipy.spatial.cKDTree`."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from shared.kernels.matching._grid import nearest_within

F = NDArray[np.float64]


def kdtree_within(ref: F, queries: F, radius: float) -> tuple[NDArray[np.intp], F]:
    dist, idx = cKDTree(ref).query(queries, distance_upper_bound=np.nextafter(radius, np.inf))
    return np.where(np.isfinite(dist), idx, -1), dist


def check_against_kdtree(ref: F, queries: F, radius: float, cell: float | None = None) -> None:
    idx, dist = nearest_within(ref, queries, radius, cell)
    want_idx, want_dist = kdtree_within(ref, queries, radius)
    found = want_idx >= 0
    assert np.array_equal(idx >= 0, found)
    np.testing.assert_allclose(dist[found], want_dist[found], rtol=1e-12, atol=1e-12)
    # the index may differ on ties, but must point at a point that far away
    np.testing.assert_allclose(np.hypot(*(ref[idx[found]] - queries[found]).T), want_dist[found], rtol=1e-12,
                               atol=1e-12)
    assert np.all(np.isinf(dist[~found]))


coords = st.floats(-20.0, 20.0, allow_nan=False, allow_infinity=False)


@settings(max_examples=80, deadline=None)
@given(
    ref=arrays(np.float64, st.tuples(st.integers(1, 120), st.just(2)), elements=coords),
    queries=arrays(np.float64, st.tuples(st.integers(1, 60), st.just(2)), elements=coords),
    radius=st.floats(1e-3, 30.0),
    cell_ratio=st.sampled_from([None, 0.05, 1.0, 3.0]),
)
def test_matches_kdtree(ref: F, queries: F, radius: float, cell_ratio: float | None) -> None:
    check_against_kdtree(ref, queries, radius, None if cell_ratio is None else radius * cell_ratio)


def test_scan_like_data_and_far_queries() -> None:
    rng = np.random.default_rng(0)
    t = np.linspace(0, 1, 600)
    walls = np.concatenate([np.stack([6 * t, 0 * t], 1), np.stack([6 + 0 * t, 4 * t], 1)])
    ref = walls + rng.normal(0, 0.01, (1200, 2))
    queries = np.concatenate([ref[::3] + rng.normal(0, 0.05, (400, 2)), rng.uniform(-100, 100, (100, 2))])
    for radius in (0.01, 0.1, 0.3, 2.0):
        check_against_kdtree(ref, queries, radius)


def test_duplicates_non_finite_and_huge_spread() -> None:
    ref = np.array([[1.0, 1.0]] * 10 + [[np.nan, 0.0], [1e6, -1e6], [-1e6, 1e6]])
    queries = np.array([[1.0, 1.0], [1.05, 1.0], [np.inf, 0.0], [1e6, -1e6 + 0.1], [0.0, 0.0]])
    idx, dist = nearest_within(ref, queries, 0.2)
    assert 0 <= idx[0] < 10
    assert dist[0] == 0.0
    assert 0 <= idx[1] < 10
    assert abs(dist[1] - 0.05) < 1e-12
    assert idx[2] == -1
    assert np.isinf(dist[2])
    assert idx[3] == 11
    assert idx[4] == -1
    empty_idx, empty_dist = nearest_within(np.zeros((0, 2)), queries, 1.0)
    assert np.all(empty_idx == -1)
    assert np.all(np.isinf(empty_dist))
