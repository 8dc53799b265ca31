"""Property tests of the declared map bounds (:mod:`server.mapbounds`): an upload is accepted exactly when
every value lies within its bound, and a refusal names the field, the value and the bound."""

from __future__ import annotations

import math
from typing import Any

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from server.errors import InvalidRequestError
from server.mapbounds import ANGLE_MAX_RAD, ID_MAX, STAMP_MAX_S, check_upload_bounds, screen_stored
from server.schemas import MapOut, MapUpload

EXTENT_M = 10_000.0
finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
inside = st.floats(-EXTENT_M, EXTENT_M)
outside = st.one_of(
    st.floats(min_value=EXTENT_M, exclude_min=True), st.floats(max_value=-EXTENT_M, exclude_max=True)
).filter(math.isfinite)
angle = st.floats(-ANGLE_MAX_RAD, ANGLE_MAX_RAD)
stamp = st.floats(0.0, STAMP_MAX_S)
seg_id = st.integers(0, ID_MAX)
segment = st.tuples(seg_id, inside, inside, inside, inside).map(list)
traj = st.tuples(stamp, inside, inside, angle).map(list)


def _upload(**fields: Any) -> MapUpload:
    return MapUpload.model_validate({"version": 1, **fields})


@settings(max_examples=200, deadline=None)
@given(
    segments=st.lists(segment, max_size=20),
    centroids=st.lists(st.tuples(inside, inside).map(list), max_size=5),
    trajectory=st.lists(traj, max_size=5),
    pose=st.tuples(inside, inside, angle).map(list),
    stamp_s=stamp,
)
def test_values_within_the_bounds_are_accepted(
    segments: list[Any], centroids: list[Any], trajectory: list[Any], pose: list[Any], stamp_s: float
) -> None:
    up = _upload(segments=segments, centroids=centroids, trajectory=trajectory, pose=pose, stamp_s=stamp_s)
    check_upload_bounds(up, EXTENT_M)


@settings(max_examples=300, deadline=None)
@given(
    segments=st.lists(segment, min_size=1, max_size=20),
    data=st.data(),
)
def test_one_coordinate_outside_is_refused_naming_it(
    segments: list[list[float]], data: st.DataObject
) -> None:
    row = data.draw(st.integers(0, len(segments) - 1))
    col = data.draw(st.integers(1, 4))
    bad = data.draw(outside)
    segments[row][col] = bad
    with pytest.raises(InvalidRequestError) as err:
        check_upload_bounds(_upload(segments=segments), EXTENT_M)
    assert err.value.extra["field"] == f"segments[{row}][{col}]"
    assert err.value.extra["value"] == bad
    assert repr(bad) in str(err.value) and "world_extent_m" in str(err.value)
    assert err.value.extra["bound"]["max"] == EXTENT_M


@settings(max_examples=200, deadline=None)
@given(sid=st.integers(ID_MAX + 1, 2**53), at=st.integers(0, 3))
def test_an_id_beyond_32_bits_is_refused(sid: int, at: int) -> None:
    segments = [[i, 0.0, 0.0, 1.0, 1.0] for i in range(4)]
    segments[at][0] = sid
    with pytest.raises(InvalidRequestError) as err:
        check_upload_bounds(_upload(segments=segments), EXTENT_M)
    assert err.value.extra["field"] == f"segments[{at}][0]"
    assert str(ID_MAX) in str(err.value)


@settings(max_examples=200, deadline=None)
@given(theta=finite.filter(lambda t: abs(t) > ANGLE_MAX_RAD), where=st.sampled_from(["pose", "trajectory"]))
def test_a_heading_beyond_2_pi_is_refused(theta: float, where: str) -> None:
    if where == "pose":
        up, field = _upload(pose=[0.0, 0.0, theta]), "pose[2]"
    else:
        up, field = _upload(trajectory=[[0.0, 0.0, 0.0, theta]]), "trajectory[0][3]"
    with pytest.raises(InvalidRequestError) as err:
        check_upload_bounds(up, EXTENT_M)
    assert err.value.extra["field"] == field


@settings(max_examples=200, deadline=None)
@given(
    good=st.lists(segment, max_size=10),
    bad=st.lists(st.tuples(seg_id, outside, inside, inside, inside).map(list), max_size=10),
)
def test_a_stored_map_is_screened_to_exactly_its_rows_within_bounds(
    good: list[list[float]], bad: list[list[float]]
) -> None:
    rows = [[float(v) for v in r] for r in good + bad]
    m = MapOut(
        robot_id=1, version=1, stamp_s=0.0, segments=rows, centroids=[], pose=[0.0, 0.0, 0.0], trajectory=[]
    )
    screen = screen_stored(m, EXTENT_M)
    assert screen.kept.segments == rows[: len(good)]
    assert screen.skipped == ({"walls": len(bad)} if bad else {})
    assert (screen.first is None) == (not bad)
