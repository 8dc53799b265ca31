"""Properties of the snapshot diff (server.snapdiff): applied to the stored map, the diff gives exactly the
snapshot's map (walls by id, bit for bit, a repeated id keeping its last row; the trajectory in order), and
it holds only what differs."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from server.snapdiff import StoredMap, apply_diff, diff_snapshot, last_rows

# few distinct values (and both zeros) so that stored and snapshot walls often coincide or differ by a bit
_COORD = st.sampled_from([0.0, -0.0, 1.0, 1.5, -2.25, 1e-9, 123.456])
_WALL = st.tuples(st.integers(0, 40), _COORD, _COORD, _COORD, _COORD)
_POSE = st.tuples(st.sampled_from([0.0, 0.5, 1.0]), _COORD, _COORD, _COORD)


def _stored(
    version: int, walls: list[tuple[int, float, float, float, float]], traj: Sequence[tuple[float, ...]]
) -> StoredMap:
    ids, coords = last_rows(np.array(walls, dtype=np.float64).reshape(-1, 5))
    return StoredMap(version, ids, coords, np.array(traj, dtype=np.float64).reshape(-1, 4))


def _bits(a: np.ndarray) -> list[int]:
    return np.ascontiguousarray(a, dtype=np.float64).view(np.int64).ravel().tolist()


def _want(segments: np.ndarray) -> dict[int, list[int]]:
    """The full replace's walls: the last row of each id (server.mapstore.prepare_rows)."""
    return {int(r[0]): _bits(r[1:5]) for r in segments}


@st.composite
def _case(draw: st.DrawFn) -> tuple[StoredMap, np.ndarray, np.ndarray]:
    """A stored map and a snapshot: either unrelated, or the stored map changed a little (walls moved,
    dropped, added; the trajectory extended, cut or altered)."""
    walls = draw(st.lists(_WALL, max_size=30))
    traj = draw(st.lists(_POSE, max_size=12))
    stored = _stored(draw(st.integers(0, 10)), walls, traj)
    if draw(st.booleans()):
        new_walls = draw(st.lists(_WALL, max_size=30))
        new_traj = draw(st.lists(_POSE, max_size=12))
    else:
        new_walls = []
        for w in np.column_stack([stored.wall_ids, stored.walls]).tolist():
            act = draw(st.sampled_from(["keep", "keep", "move", "drop"]))
            if act != "drop":
                new_walls.append(tuple(w) if act == "keep" else (w[0], *draw(_WALL)[1:]))
        new_walls = draw(st.permutations(new_walls + draw(st.lists(_WALL, max_size=8))))
        new_traj = [tuple(p) for p in stored.trajectory.tolist()]
        how = draw(st.sampled_from(["extend", "same", "cut", "alter"]))
        if how == "extend":
            new_traj += draw(st.lists(_POSE, max_size=6))
        elif how == "cut" and new_traj:
            new_traj = new_traj[: draw(st.integers(0, len(new_traj) - 1))]
        elif how == "alter" and new_traj:
            i = draw(st.integers(0, len(new_traj) - 1))
            new_traj[i] = draw(_POSE)
    segs = np.array(new_walls, dtype=np.float64).reshape(-1, 5)
    return stored, segs, np.array(new_traj, dtype=np.float64).reshape(-1, 4)


@settings(max_examples=400, deadline=None)
@given(_case())
def test_applying_the_diff_gives_exactly_the_snapshots_map(
    case: tuple[StoredMap, np.ndarray, np.ndarray],
) -> None:
    stored, segs, traj = case
    diff = diff_snapshot(stored, segs, traj)
    ids, coords, got_traj = apply_diff(stored, diff)
    assert {int(i): _bits(c) for i, c in zip(ids, coords, strict=True)} == _want(segs)
    assert ids.tolist() == sorted(_want(segs))
    assert _bits(got_traj) == _bits(traj) and got_traj.shape == traj.shape


@settings(max_examples=300, deadline=None)
@given(_case())
def test_the_diff_holds_only_what_differs(case: tuple[StoredMap, np.ndarray, np.ndarray]) -> None:
    stored, segs, traj = case
    diff = diff_snapshot(stored, segs, traj)
    old = {int(i): _bits(c) for i, c in zip(stored.wall_ids, stored.walls, strict=True)}
    want = _want(segs)
    assert sorted(diff.removed.tolist()) == sorted(set(old) - set(want))
    assert {int(r[0]): _bits(r[1:5]) for r in diff.upsert} == {
        i: bits for i, bits in want.items() if old.get(i) != bits
    }
    k = len(stored.trajectory)
    extends = len(traj) >= k and _bits(traj[:k]) == _bits(stored.trajectory)
    assert diff.replace_trajectory is not extends
    assert _bits(diff.trajectory) == _bits(traj[k:] if extends else traj)


def test_a_repeated_snapshot_is_an_empty_diff_and_an_extension_appends_only_the_new_poses() -> None:
    walls = np.array([[float(i), i, 0.0, i + 0.5, 1.0] for i in range(1000)])
    traj = np.array([[0.1 * j, 1.0, 2.0, 0.0] for j in range(500)])
    ids, coords = last_rows(walls)
    stored = StoredMap(7, ids, coords, traj)
    same = diff_snapshot(stored, walls, traj)
    assert same.rows == 0 and not same.replace_trajectory and same.base_version == 7
    moved = walls.copy()
    moved[10, 4] = -0.0 + 1.25
    more = np.concatenate([traj, [[99.0, 1.0, 2.0, 0.0]]])
    d = diff_snapshot(stored, moved[1:], more)  # wall 0 gone, wall 10 moved, one pose more
    assert d.removed.tolist() == [0] and d.upsert[:, 0].tolist() == [10.0]
    assert not d.replace_trajectory and d.trajectory.tolist() == [[99.0, 1.0, 2.0, 0.0]]


def test_negative_zero_counts_as_a_change_and_a_diff_of_another_version_is_refused() -> None:
    stored = StoredMap(3, np.array([5]), np.array([[0.0, 0.0, 1.0, 1.0]]), np.empty((0, 4)))
    d = diff_snapshot(stored, np.array([[5.0, -0.0, 0.0, 1.0, 1.0]]), np.empty((0, 4)))
    assert d.upsert.shape == (1, 5) and np.signbit(d.upsert[0, 1])
    with pytest.raises(ValueError, match="diff from version 3 applied to version 4"):
        apply_diff(StoredMap(4, stored.wall_ids, stored.walls, stored.trajectory), d)
