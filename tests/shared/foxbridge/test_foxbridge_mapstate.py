"""The bridge's copy of a robot's map (shared/foxbridge/mapstate.py): a snapshot then deltas give the map
the server holds; a delta out of step is refused; a malformed event names its field."""

from __future__ import annotations

import math
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from shared.foxbridge.errors import MapEventError, OutOfStepError
from shared.foxbridge.mapstate import apply_delta, apply_event, from_snapshot

coord = st.floats(-1e3, 1e3, allow_nan=False)
wall_ids = st.integers(0, 50)


def _snapshot(segments: dict[int, list[float]], version: int = 1, **extra: Any) -> dict[str, Any]:
    return {
        "robot_id": 7,
        "version": version,
        "map_session": None,
        "stamp_s": 1.0,
        "segments": [[i, *s] for i, s in sorted(segments.items())],
        "centroids": [],
        "pose": [0.0, 0.0, 0.0],
        "trajectory": [],
        **extra,
    }


steps = st.lists(
    st.tuples(
        st.dictionaries(wall_ids, st.lists(coord, min_size=4, max_size=4), max_size=5),  # set
        st.lists(wall_ids, max_size=5),  # removed
        st.tuples(coord, coord, st.floats(-math.pi, math.pi)),  # pose
        st.lists(st.tuples(coord, coord), max_size=3),  # centroids
    ),
    max_size=12,
)


@given(st.dictionaries(wall_ids, st.lists(coord, min_size=4, max_size=4), max_size=10), steps)
def test_a_snapshot_then_deltas_give_the_map_of_the_last_version(
    first: dict[int, list[float]], changes: list[Any]
) -> None:
    truth = dict(first)
    poses: list[list[float]] = []
    state = from_snapshot(_snapshot(first))
    for n, (changed, removed, pose, centroids) in enumerate(changes, start=2):
        for i in removed:
            truth.pop(i, None)
        truth.update(changed)
        poses.append([float(n), pose[0], pose[1], pose[2]])
        delta = {
            "kind": "delta",
            "version": n,
            "base_version": n - 1,
            "stamp_s": float(n),
            "segments": [[i, *s] for i, s in changed.items()],
            "removed": removed,
            "centroids": [list(c) for c in centroids],
            "pose": list(pose),
            "trajectory": [poses[-1]],
        }
        state = apply_event(state, "delta", delta)
        assert state.version == n and state.pose == pose and state.centroids == tuple(centroids)
    assert {i: list(s) for i, s in state.segments.items()} == truth
    assert [list(r) for r in state.trajectory] == poses


def test_the_trajectory_keeps_the_newest_poses() -> None:
    rows = [[float(i), float(i), 0.0, 0.0] for i in range(10)]
    state = from_snapshot(_snapshot({}, trajectory=rows), keep=4)
    assert [r[0] for r in state.trajectory] == [6.0, 7.0, 8.0, 9.0]
    delta = {"version": 2, "base_version": 1, "trajectory": [[10.0, 1.0, 1.0, 0.0]]}
    assert [r[0] for r in apply_delta(state, delta, keep=4).trajectory] == [7.0, 8.0, 9.0, 10.0]


def test_a_delta_that_does_not_continue_the_held_version_is_out_of_step() -> None:
    state = from_snapshot(_snapshot({1: [0.0, 0.0, 1.0, 0.0]}, version=5))
    with pytest.raises(OutOfStepError, match="from version 3 does not continue version 5"):
        apply_delta(state, {"version": 4, "base_version": 3})
    with pytest.raises(OutOfStepError, match="before any snapshot"):
        apply_event(None, "delta", {"version": 4, "base_version": 3})


@pytest.mark.parametrize(
    ("change", "named"),
    [
        ({"segments": [[1, 0.0, 0.0, 1.0]]}, r"segments\[0\]: expected a row of 5 numbers"),
        ({"segments": [[1.5, 0.0, 0.0, 1.0, 1.0]]}, r"segments\[0\]: expected a whole wall id"),
        ({"segments": [[1, 0.0, None, 1.0, 1.0]]}, r"segments\[0\]: expected a finite number, got None"),
        ({"segments": "walls"}, r"segments: expected a list of rows, got str"),
        ({"pose": [1.0, 2.0]}, r"pose: expected \[x_m, y_m, theta_rad\]"),
        ({"trajectory": [[0.0, 1.0, 2.0]]}, r"trajectory\[0\]: expected a row of 4 numbers"),
        ({"version": -1}, r"version: expected a whole number >= 0, got -1"),
        ({"robot_id": "7"}, r"robot_id: expected a whole number >= 0"),
        ({"map_session": 3}, r"map_session: expected a string or null"),
    ],
)
def test_a_malformed_snapshot_names_its_field(change: dict[str, Any], named: str) -> None:
    with pytest.raises(MapEventError, match=named):
        from_snapshot({**_snapshot({}), **change})


def test_an_unknown_event_type_is_refused() -> None:
    with pytest.raises(MapEventError, match="'hello': expected 'snapshot' or 'delta'"):
        apply_event(None, "hello", {})


def test_a_delta_with_bad_removed_ids_names_them() -> None:
    state = from_snapshot(_snapshot({}))
    with pytest.raises(MapEventError, match="removed: expected a list of wall ids"):
        apply_delta(state, {"version": 2, "base_version": 1, "removed": ["a"]})
