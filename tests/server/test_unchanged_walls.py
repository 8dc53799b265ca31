"""Walls a delta sends again exactly as they are stored are not written again (server/maphistory.py
``undo_record``, server/mapstore.py): the map read back is the same as if they were, and they keep the
version that last wrote them. Through the real server on both backends, and the selection alone."""

from __future__ import annotations

from server.maphistory import UndoReads, undo_record
from server.schemas import MapUpload
from tests.server.live import Live
from tests.server.test_pgrows import _walls as stored_walls


def test_the_unchanged_walls_are_those_sent_as_stored_and_not_removed() -> None:
    up = MapUpload.model_validate(
        {
            "version": 2,
            "base_version": 1,
            # 1 as stored; 2 moved; 3 sent twice, last as stored; 4 as stored but also removed; 5 new
            "segments": [
                [1, 0, 0, 1, 1],
                [2, 0, 0, 1, 2],
                [3, 9, 9, 9, 9],
                [3, 0, 0, 3, 3],
                [4, 0, 0, 4, 4],
                [5, 0, 0, 5, 5],
            ],
            "removed": [4],
        }
    )
    stored = [
        (1, 0.0, 0.0, 1.0, 1.0),
        (2, 0.0, 0.0, 1.0, 1.0),
        (3, 0.0, 0.0, 3.0, 3.0),
        (4, 0.0, 0.0, 4.0, 4.0),
    ]
    assert undo_record(up, UndoReads(stored, True, None))[1] == {1, 3}


def _versions(live: Live, rid: int) -> dict[int, tuple[float, float, float, float, int]]:
    return {row[0]: row[1:] for row in stored_walls(live, rid)}


def test_a_delta_resending_walls_leaves_them_as_they_were(live: Live) -> None:
    rid, token = live.new_robot()
    first = {
        "version": 1,
        "base_version": None,
        "segments": [[i, 0.0, 0.0, float(i), 0.5] for i in range(1, 6)],
        "pose": [0, 0, 0],
    }
    delta = {
        "version": 2,
        "base_version": 1,
        # 1, 2 as stored; 3 moved; 4 removed; 5 removed and sent again as stored; 6 new
        "segments": [
            [1, 0.0, 0.0, 1.0, 0.5],
            [2, 0.0, 0.0, 2.0, 0.5],
            [3, 0.0, 0.0, 3.0, 0.75],
            [5, 0.0, 0.0, 5.0, 0.5],
            [6, 1.0, 1.0, 2.0, 2.0],
        ],
        "removed": [4, 5],
        "pose": [0, 0, 0],
    }
    with live.client(token) as robot:
        for body in (first, delta):
            r = robot.post(f"/robots/{rid}/maps", json=body)
            assert r.status_code == 200, r.text
    assert _versions(live, rid) == {
        1: (0.0, 0.0, 1.0, 0.5, 1),
        2: (0.0, 0.0, 2.0, 0.5, 1),
        3: (0.0, 0.0, 3.0, 0.75, 2),
        5: (0.0, 0.0, 5.0, 0.5, 2),
        6: (1.0, 1.0, 2.0, 2.0, 2),
    }
    with live.operator() as op:
        got = op.get(f"/robots/{rid}/maps/latest").json()
        assert [row[0] for row in got["segments"]] == [1, 2, 3, 5, 6]
        back = op.get(
            f"/robots/{rid}/maps/latest", params={"version": 1}
        ).json()  # the undo still rebuilds v1
        assert back["segments"] == first["segments"]
