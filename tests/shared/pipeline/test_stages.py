"""The scheduled stages on chunks: segment-wise clustering, noise chains, centroid-based lines."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from shared.kernels import REGISTRY, NoiseResult, Stage
from shared.kernels.base import takes_spacing
from shared.kernels.noise.dbscan import Dbscan
from shared.pipeline.stages import Chunk, cluster, extract_lines, remove_noise


def two_walls() -> Chunk:
    """An L corner: 200 points on y = 0 (group 0) and 100 on x = 0 (group 1), 1 mm noise."""
    rng = np.random.default_rng(0)
    a = np.column_stack([np.linspace(0.1, 4.0, 200), rng.normal(0, 0.001, 200)])
    b = np.column_stack([rng.normal(0, 0.001, 100), np.linspace(0.1, 2.0, 100)])
    return Chunk.of(np.vstack([a, b]), np.repeat(np.array([0, 1], dtype=np.intp), [200, 100]))


def with_k(k: int) -> object:
    return REGISTRY.create(Stage.CLUSTERING, "kmeans", {"n_clusters": k})


def test_clusters_never_straddle_segments() -> None:
    chunk = two_walls()
    out = cluster(REGISTRY.create(Stage.CLUSTERING, "kmeans", {"n_clusters": 6}), chunk, with_k)
    assert len(out.centroids) == 6
    assert list(np.bincount(out.centroid_groups)) == [4, 2], "shares follow the point counts"
    on_a = out.centroids[out.centroid_groups == 0]
    on_b = out.centroids[out.centroid_groups == 1]
    assert np.all(np.abs(on_a[:, 1]) < 0.01) and np.all(np.abs(on_b[:, 0]) < 0.01), "centroids lie on walls"


def test_small_budgets_go_to_the_big_segments_and_k1_is_the_mean() -> None:
    chunk = two_walls()
    out = cluster(REGISTRY.create(Stage.CLUSTERING, "fcm", {"n_clusters": 1}), chunk, with_k)
    assert len(out.centroids) == 1 and list(out.centroid_groups) == [0], "1/3 of a cluster rounds to none"
    np.testing.assert_allclose(out.centroids[0], chunk.points[:200].mean(axis=0))
    out = cluster(REGISTRY.create(Stage.CLUSTERING, "fcm", {"n_clusters": 2}), chunk, with_k)
    assert sorted(out.centroid_groups) == [0, 1]


def test_whole_batch_clustering_without_factory() -> None:
    out = cluster(REGISTRY.create(Stage.CLUSTERING, "kmeans", {"n_clusters": 3}), two_walls())
    assert len(out.centroids) == 3 and np.all(out.centroid_groups >= 0)


def test_svd_lines_from_centroids_span_the_points() -> None:
    chunk = cluster(REGISTRY.create(Stage.CLUSTERING, "kmeans", {"n_clusters": 6}), two_walls(), with_k)
    segs = extract_lines(REGISTRY.create(Stage.STRAIGHT_LINE, "svd"), chunk)
    assert len(segs) == 2
    lengths = np.sort(np.hypot(segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1]))
    np.testing.assert_allclose(lengths, [1.9, 3.9], atol=0.02)


def test_dilation_points_inherit_the_nearest_group() -> None:
    chunk = two_walls()
    out = remove_noise([REGISTRY.create(Stage.NOISE_REMOVAL, "dilation")], chunk)
    assert len(out.points) > len(chunk.points)
    assert len(out.groups) == len(out.points) and np.all(out.groups >= 0)


def test_regroup_unites_one_wall_seen_from_several_scans() -> None:
    from shared.pipeline.regroup import regroup

    rng = np.random.default_rng(1)
    pieces, groups = [], []
    for scan in range(4):  # four scans each see the wall y = 0 (a piece) and the wall x = 0
        x = np.linspace(0.2 + 0.3 * scan, 2.0 + 0.3 * scan, 50)
        pieces.append(np.column_stack([x, rng.normal(0, 0.005, 50)]))
        y = np.linspace(0.2, 1.5, 30)
        pieces.append(np.column_stack([rng.normal(0, 0.005, 30), y]))
        groups += [np.full(50, 2 * scan), np.full(30, 2 * scan + 1)]
    new = regroup(np.vstack(pieces), np.concatenate(groups).astype(np.intp))
    assert len(np.unique(new)) == 2
    assert len(np.unique(new[np.concatenate(groups) % 2 == 0])) == 1


def test_regroup_drops_groups_that_are_not_straight() -> None:
    from shared.pipeline.regroup import regroup

    corner = np.vstack(
        [
            np.column_stack([np.linspace(0, 1, 40), np.zeros(40)]),
            np.column_stack([np.zeros(40), np.linspace(0, 1, 40)]),
        ]
    )
    wall = np.column_stack([np.linspace(0, 2, 50), np.full(50, 3.0)])
    new = regroup(np.vstack([corner, wall]), np.repeat(np.array([0, 1], dtype=np.intp), [80, 50]))
    assert np.all(new[:80] == -1), "a piece around a corner is no wall"
    assert np.all(new[80:] == 0)


def test_regroup_does_not_chain_perpendicular_walls_through_corner_pieces() -> None:
    """Short pieces turning 4 degrees at a time round a corner are each collinear with the next; uniting
    pairs transitively would make both walls one group whose line crosses the room."""
    from shared.pipeline.regroup import regroup

    wall_a = np.column_stack([np.linspace(0.0, 2.6, 120), np.zeros(120)])
    wall_b = np.column_stack([np.full(120, 3.0), np.linspace(0.4, 3.0, 120)])
    pts, grp = [wall_a, wall_b], [np.zeros(120), np.ones(120)]
    centre, r = np.array([2.6, 0.4]), 0.4
    for i, ang in enumerate(np.radians(np.arange(0.0, 91.0, 4.0))):
        foot = centre + r * np.array([np.sin(ang), -np.cos(ang)])
        tangent = np.array([np.cos(ang), np.sin(ang)])
        pts.append(foot + np.outer(np.linspace(-0.05, 0.05, 4), tangent))
        grp.append(np.full(4, 2 + i))
    new = regroup(np.vstack(pts), np.concatenate(grp).astype(np.intp))
    assert len(np.unique(new[:120])) == 1 and len(np.unique(new[120:240])) == 1
    assert new[0] != new[120], "perpendicular walls must stay apart"


def test_regroup_joins_two_pieces_of_a_wall_bridged_later() -> None:
    from shared.pipeline.regroup import regroup

    left = np.column_stack([np.linspace(0.0, 2.0, 100), np.zeros(100)])
    right = np.column_stack([np.linspace(2.5, 4.0, 90), np.full(90, 0.01)])
    middle = np.column_stack([np.linspace(1.5, 2.7, 10), np.full(10, 0.005)])
    groups = np.repeat(np.array([0, 1, 2], dtype=np.intp), [100, 90, 10])
    new = regroup(np.vstack([left, right, middle]), groups)
    assert len(np.unique(new)) == 1


def test_centroid_join_reaches_the_ends_of_its_wall() -> None:
    chunk = cluster(REGISTRY.create(Stage.CLUSTERING, "kmeans", {"n_clusters": 6}), two_walls(), with_k)
    segs = extract_lines(REGISTRY.create(Stage.STRAIGHT_LINE, "centroid-join"), chunk)
    on_a = segs[np.abs(segs[:, 1]) < 0.01]
    xs = np.concatenate([on_a[:, 0], on_a[:, 2]])
    assert xs.min() == pytest.approx(0.1, abs=0.01) and xs.max() == pytest.approx(4.0, abs=0.01)


def test_noise_floored_uncertainty_takes_the_range_noise_as_the_least_scatter() -> None:
    from shared.pipeline.rangenoise import NO_RANGE_NOISE, RangeNoise
    from shared.pipeline.stages import Chunk, noise_floored_uncertainty

    segs = np.array([[3.8, -0.2, 3.8, 0.2], [1.0, -0.2, 1.0, 0.2], [2.0, 0.0, 2.0, 0.1]])
    chunk = Chunk.of(np.zeros((0, 2)), np.zeros(0, dtype=np.intp), viewpoint=(-0.2, 0.0))
    sig, sd = np.array([0.006, 0.03, 0.0]), np.array([0.02, 0.1, 0.0])
    noise = RangeNoise(near_m=0.0125, ratio=0.0125)
    floored, honest = noise_floored_uncertainty(segs, chunk, sig, sd, noise)
    assert floored[0] == pytest.approx(0.05) and honest[0] == pytest.approx(0.02 * 0.05 / 0.006)
    assert floored[1] == 0.03 and honest[1] == 0.1  # noisier than the model already
    assert floored[2] == 0.0 and honest[2] == 0.0  # unknown stays unknown
    same = noise_floored_uncertainty(segs, chunk, sig, sd, NO_RANGE_NOISE)
    assert np.array_equal(same[0], sig) and np.array_equal(same[1], sd)


def test_remove_noise_hands_the_beam_spacing_to_kernels_that_take_it() -> None:
    """DBSCAN widens its neighbourhood to the returns' spacing; the erosion after it (no ``uses_spacing``)
    gets the points alone; the spacing follows the kept points; chunks without one are the paper's."""
    xs = np.arange(0.0, 3.0, 0.2)  # a wall sampled every 20 cm: noise at epsilon 5 cm
    pts = np.column_stack([xs, np.full(len(xs), 8.0)])
    groups = np.zeros(len(xs), dtype=np.intp)
    spacing = np.full(len(xs), 0.2)
    dbscan = REGISTRY.create(Stage.NOISE_REMOVAL, "dbscan", {})
    assert takes_spacing(dbscan)
    assert len(remove_noise([dbscan], Chunk.of(pts, groups)).points) == 0
    out = remove_noise([dbscan], Chunk.of(pts, groups, (0.0, 0.0), spacing))
    assert len(out.points) == len(xs)
    assert out.spacing_m is not None and np.array_equal(out.spacing_m, spacing)
    erosion = REGISTRY.create(Stage.NOISE_REMOVAL, "erosion", {})
    assert not takes_spacing(erosion)
    chained = remove_noise([dbscan, erosion], Chunk.of(pts, groups, (0.0, 0.0), spacing))
    assert chained.spacing_m is not None and len(chained.spacing_m) == len(chained.points)


def test_a_subclass_that_overrides_apply_without_spacing_is_called_with_points_alone() -> None:
    """A kernel derived from DBSCAN whose ``apply`` takes the points only (written before the spacing
    existed) inherits ``uses_spacing`` but is not handed an argument it cannot take."""

    class Old(Dbscan):
        def apply(self, points: Any) -> NoiseResult:  # type: ignore[override]
            return super().apply(points)

    xs = np.arange(0.0, 3.0, 0.02)
    pts = np.column_stack([xs, np.full(len(xs), 2.0)])
    chunk = Chunk.of(pts, np.zeros(len(xs), dtype=np.intp), (0.0, 0.0), np.full(len(xs), 0.02))
    assert not takes_spacing(Old())
    assert len(remove_noise([Old()], chunk).points) == len(xs)
