"""Exact point-to-segment search: the indexed path agrees with brute force."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import shared.metrics.distance as distance
from shared.metrics.distance import (
    nearest_segment,
    paired_distance,
    sample_segments,
    segment_lengths,
    spaced_points,
    within_distance,
)
from shared.types import FloatArray

coord = st.floats(-3.0, 3.0)
segment_sets = st.lists(st.tuples(coord, coord, coord, coord), min_size=1, max_size=12).map(
    lambda rows: np.array(rows, dtype=np.float64)
)
point_sets = st.lists(st.tuples(st.floats(-4, 4), st.floats(-4, 4)), min_size=1, max_size=30).map(
    lambda rows: np.array(rows, dtype=np.float64)
)


def reference(points: FloatArray, segments: FloatArray) -> FloatArray:
    out = np.empty(len(points))
    for k, p in enumerate(points):
        out[k] = min(paired_distance(p[None, :], s[None, :])[0] for s in segments)
    return out


def test_paired_distance_known_values() -> None:
    seg = np.array([[0.0, 0.0, 2.0, 0.0]] * 4)
    pts = np.array([[1.0, 1.0], [-1.0, 0.0], [3.0, 4.0], [0.5, 0.0]])
    np.testing.assert_allclose(paired_distance(pts, seg), [1.0, 1.0, math.hypot(1.0, 4.0), 0.0])
    # a degenerate segment is a point
    assert paired_distance(np.array([[3.0, 4.0]]), np.zeros((1, 4)))[0] == pytest.approx(5.0)


def test_sample_weights_sum_to_lengths() -> None:
    segs = np.array([[0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 0.25], [1.0, 1.0, 1.0, 1.0]])
    pts, owner, w = sample_segments(segs, 0.1)
    np.testing.assert_allclose(np.bincount(owner, w, minlength=3), segment_lengths(segs))
    assert np.count_nonzero(owner == 0) == 10 and np.count_nonzero(owner == 2) == 0
    np.testing.assert_allclose(pts[owner == 0][:, 0], np.arange(10) * 0.1 + 0.05)


def test_spaced_points_cover_every_segment() -> None:
    segs = np.array([[0.0, 0.0, 1.0, 0.0], [2.0, 2.0, 2.0, 2.0]])
    pts, owner = spaced_points(segs, 0.3)
    assert np.count_nonzero(owner == 0) == 5 and np.count_nonzero(owner == 1) == 2
    assert np.max(np.diff(pts[owner == 0][:, 0])) <= 0.3


@settings(max_examples=80, deadline=None)
@given(point_sets, segment_sets, st.booleans())
def test_nearest_segment_is_exact_on_both_paths(points: FloatArray, segs: FloatArray, indexed: bool) -> None:
    with pytest.MonkeyPatch.context() as mp:
        if indexed:
            mp.setattr(distance, "_BRUTE_PAIRS", 0)
        dist, index = nearest_segment(points, segs)
        near = within_distance(points, segs, 0.3)
    ref = reference(points, segs)
    np.testing.assert_allclose(dist, ref, atol=1e-12)
    np.testing.assert_allclose(paired_distance(points, segs[index]), ref, atol=1e-12)
    np.testing.assert_array_equal(near, ref <= 0.3)


def test_crowded_points_fall_back_to_brute_force(monkeypatch: pytest.MonkeyPatch) -> None:
    # 60 copies of a wall: every point has more candidates than the k-d tree rounds check
    segs = np.tile([[0.0, 0.0, 1.0, 0.0]], (60, 1)) + np.linspace(0.0, 0.06, 60)[:, None] * [0, 1, 0, 1]
    segs = np.vstack([segs, [[5.0, 5.0, 6.0, 5.0]]])
    points = np.array([[0.5, -0.2], [0.5, 0.03], [5.5, 4.0], [3.0, 3.0]])
    calls: list[int] = []
    brute = distance._brute

    def spy(p: FloatArray, s: FloatArray) -> tuple[FloatArray, np.ndarray]:
        calls.append(len(p))
        return brute(p, s)

    monkeypatch.setattr(distance, "_BRUTE_PAIRS", 0)
    monkeypatch.setattr(distance, "_brute", spy)
    dist, _ = nearest_segment(points, segs)
    np.testing.assert_allclose(dist, reference(points, segs), atol=1e-12)
    assert calls, "expected the brute-force fallback to run"


def test_max_distance_marks_far_points(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(distance, "_BRUTE_PAIRS", 0)
    segs = np.array([[0.0, 0.0, 1.0, 0.0]])
    dist, index = nearest_segment(np.array([[0.5, 0.04], [0.5, 0.5]]), segs, max_distance_m=0.05)
    assert dist[0] == pytest.approx(0.04) and index[0] == 0
    assert math.isinf(dist[1]) and index[1] == -1


def test_no_segments() -> None:
    dist, index = nearest_segment(np.zeros((2, 2)), np.zeros((0, 4)))
    assert np.all(np.isinf(dist)) and np.all(index == -1)
    assert not within_distance(np.zeros((2, 2)), np.zeros((0, 4)), 1.0).any()
