"""shared.protocol.posegraph and the pose graph's fields of MapUpload: keyframes, loop closures and the pose
covariance round-trip through JSON, bad ones are refused naming what was wrong, an upload without them
serialises as before them, and a keyframe correction moves the trajectory as the robot's own rule does."""

from __future__ import annotations

import json
import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from pydantic import ValidationError

from shared.protocol import (
    MAX_TRAJECTORY_POSES,
    MapDelta,
    MapSnapshot,
    MapUpload,
    check_covariance,
    correct_trajectory,
    keyframes_in_use,
    sigmas,
    thin_positions,
)
from shared.types import FloatArray, Pose2D

_F = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)
_ANGLE = st.floats(-math.pi, math.pi, allow_nan=False)


@st.composite
def _covariances(draw: st.DrawFn) -> list[list[float]]:
    """Random covariances A A^T (positive semi-definite, symmetric to the last bit)."""
    a = np.array(draw(st.lists(st.floats(-10, 10, allow_nan=False), min_size=9, max_size=9))).reshape(3, 3)
    cov = a @ a.T
    return [[float(cov[i][j]) for j in range(3)] for i in range(3)]


@st.composite
def _graphs(draw: st.DrawFn) -> tuple[list[list[float]], list[list[int]]]:
    ids = draw(st.lists(st.integers(0, 2**53), min_size=0, max_size=12, unique=True))
    rows = [[float(i), draw(_F), draw(_F), draw(_F), draw(_ANGLE)] for i in ids]
    pairs = draw(st.lists(st.tuples(st.sampled_from(ids), st.sampled_from(ids)), max_size=6)) if ids else []
    return rows, [[int(a), int(b)] for a, b in pairs]


@given(_graphs(), _covariances())
def test_graph_fields_round_trip(
    graph: tuple[list[list[float]], list[list[int]]], cov: list[list[float]]
) -> None:
    keyframes, closures = graph
    snap = MapSnapshot(version=3, keyframes=keyframes, loop_closures=closures, pose_covariance=cov)
    text = json.dumps(snap.model_dump(mode="json"))
    again = MapUpload.model_validate_json(text)
    assert again.keyframes == keyframes
    assert again.loop_closures == closures
    assert again.pose_covariance == cov
    delta = MapDelta(version=4, base_version=3, keyframes=keyframes[:1], loop_closures=[[7, 9]])
    assert MapDelta.model_validate_json(delta.model_dump_json()).loop_closures == [[7, 9]]


def test_absent_graph_fields_are_left_out_of_the_json() -> None:
    """An older server forbids unknown fields: a robot without a pose graph sends none of them."""
    body = MapDelta(version=2, base_version=1).model_dump(mode="json")
    assert not {"keyframes", "loop_closures", "pose_covariance"} & set(body)
    body = MapDelta(version=2, base_version=1, keyframes=[]).model_dump(mode="json")
    assert body["keyframes"] == [] and "loop_closures" not in body


@pytest.mark.parametrize(
    ("fields", "words"),
    [
        ({"keyframes": [[1.5, 0, 0, 0, 0]]}, "keyframe id must be an integer"),
        ({"keyframes": [[2.0**60, 0, 0, 0, 0]]}, "in 0..2\\*\\*53"),
        ({"keyframes": [[1, 0, 0, 0, 0], [1, 1, 0, 0, 0]]}, "keyframe 1 is listed twice"),
        ({"keyframes": [[1, 0, 0, 0]]}, "at least 5"),
        ({"keyframes": [[1, 0, float("nan"), 0, 0]]}, "finite"),
        (
            {"loop_closures": [[1, 2]], "keyframes": [[1, 0, 0, 0, 0]]},
            "names a keyframe the snapshot does not list",
        ),
        ({"loop_closures": [[-1, 2]]}, "greater than or equal to 0"),
        ({"pose_covariance": [[1, 0, 0], [0, 1, 0]]}, "at least 3"),
        ({"pose_covariance": [[1, 0.5, 0], [0, 1, 0], [0, 0, 1]]}, "must be symmetric"),
        ({"pose_covariance": [[1, 2, 0], [2, 1, 0], [0, 0, 1]]}, "positive semi-definite"),
        ({"pose_covariance": [[1, 0, 0], [0, float("inf"), 0], [0, 0, 1]]}, "finite"),
    ],
)
def test_bad_graph_fields_are_refused_naming_the_problem(fields: dict[str, object], words: str) -> None:
    with pytest.raises(ValidationError, match=words):
        MapSnapshot.model_validate({"version": 1, **fields})


def test_a_delta_may_close_a_loop_with_keyframes_sent_before() -> None:
    d = MapDelta(version=5, base_version=4, loop_closures=[[0, 40]])
    assert d.loop_closures == [[0, 40]]


@given(_covariances())
def test_check_covariance_accepts_every_psd_matrix(cov: list[list[float]]) -> None:
    check_covariance(cov)
    sx, sy, sth = sigmas(cov)
    assert sy == pytest.approx(math.sqrt(cov[1][1]))
    assert sx == pytest.approx(math.sqrt(cov[0][0]))
    assert sth == pytest.approx(math.sqrt(cov[2][2]))


@given(
    st.lists(st.tuples(_F.map(lambda v: v / 1e3), _F.map(lambda v: v / 1e3), _ANGLE), min_size=2, max_size=8),
    st.tuples(_F.map(lambda v: v / 1e3), _F.map(lambda v: v / 1e3), _ANGLE),
    st.lists(st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)), min_size=1, max_size=20),
)
def test_correction_matches_the_mappers_rule(
    keys: list[tuple[float, float, float]],
    moved_to: tuple[float, float, float],
    offsets: list[tuple[float, float, float]],
) -> None:
    """Poses G(k) F(k)^-1 F(s) recorded under the old G(k) become those under the new G(k) for the moved
    keyframe, and stay for the others (property of the rule in shared.slam.mapper)."""
    before = {k: [float(k), *p] for k, p in enumerate(keys)}  # keyframe k at stamp k
    moved = 1
    after = {moved: [float(moved), *moved_to]}
    rows, expected = [], []
    for i, off in enumerate(offsets):
        k = i % len(keys)
        stamp = k + 0.5
        rel = Pose2D(*off)
        old = Pose2D(*keys[k]) @ rel
        new = (Pose2D(*moved_to) if k == moved else Pose2D(*keys[k])) @ rel
        rows.append([stamp, old.x_m, old.y_m, old.theta_rad])
        expected.append([stamp, new.x_m, new.y_m, new.theta_rad])
    rows.append([-1.0, 5.0, 6.0, 0.5])  # before the first keyframe: stays
    expected.append([-1.0, 5.0, 6.0, 0.5])
    got = correct_trajectory(np.array(rows), before, after)
    want = np.array(expected)
    assert np.allclose(got[:, :3], want[:, :3], atol=1e-6)
    dth = np.remainder(got[:, 3] - want[:, 3] + math.pi, 2 * math.pi) - math.pi
    assert np.allclose(dth, 0.0, atol=1e-9)


@st.composite
def _stores(draw: st.DrawFn) -> tuple[dict[int, list[float]], FloatArray, dict[int, list[float]]]:
    """Keyframes (id -> [stamp, x, y, th], ids in stamp order, stamps may repeat), a trajectory among
    them and a correction of some of them."""
    n = draw(st.integers(1, 15))
    stamps = sorted(draw(st.lists(st.integers(0, 40), min_size=n, max_size=n)))
    before = {k: [float(t), draw(_F) / 1e3, draw(_F) / 1e3, draw(_ANGLE)] for k, t in enumerate(stamps)}
    poses = sorted(draw(st.lists(st.integers(-2, 45), max_size=12)))
    traj = np.array([[t + 0.5, 0.1 * t, 1.0, 0.2] for t in poses], dtype=np.float64).reshape(-1, 4)
    moving = draw(st.lists(st.sampled_from(list(before)), max_size=n, unique=True))
    after = {k: [before[k][0], draw(_F) / 1e3, draw(_F) / 1e3, draw(_ANGLE)] for k in moving}
    return before, traj, after


@given(_stores())
def test_keyframes_owning_no_pose_move_nothing(store: tuple[Any, FloatArray, Any]) -> None:
    """Dropping the keyframes keyframes_in_use leaves out changes no correction of the poses held, the
    owners of the poses and every keyframe after the last one are kept."""
    before, traj, after = store
    used = keyframes_in_use([[k, *v] for k, v in before.items()], traj[:, 0])
    kept = {k: v for k, v in before.items() if k in used}
    whole = correct_trajectory(traj, before, after)
    pruned = correct_trajectory(traj, kept, {k: v for k, v in after.items() if k in used})
    np.testing.assert_allclose(pruned, whole, rtol=0, atol=1e-9)  # an unmoved owner: identity, rounded
    last = float(traj[:, 0].max()) if len(traj) else -np.inf
    assert {k for k, v in before.items() if v[0] > last} <= used
    assert max(before) in used, "the newest keyframe is always kept"
    assert len(used) <= len(traj) + sum(v[0] > last for v in before.values())


def test_keyframes_in_use_of_a_long_patrol_are_about_one_per_kept_pose() -> None:
    """70,000 keyframes (a day at 0.5 m/s, one per 50 cm) under a trajectory thinned to 8,000 poses."""
    n_poses = 864_000
    stamps = np.arange(n_poses) * 0.1
    keep = np.ones(n_poses, dtype=bool)
    keep[thin_positions(n_poses)] = False
    keyframes = [[float(k), 1.234 * k, 0.0, 0.0, 0.0] for k in range(70_000)]  # a keyframe each 1.234 s
    used = keyframes_in_use(keyframes, stamps[keep])
    assert 1 < len(used) <= MAX_TRAJECTORY_POSES + 1
    assert 69_999 in used and 0 in used
