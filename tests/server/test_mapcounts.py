"""The stored counts of a robot's walls and poses (server/mapcounts.py, ``map_states.n_walls`` /
``n_poses``): the arithmetic against sets (property test), the counts against the rows after every kind
of upload through the real server on both backends (deltas that remove, resend and add walls, snapshots
with repeated ids, a new map session, a trajectory thinned past its cap), a drift found and corrected with
a warning, and the migration counting the rows stored before it."""

from __future__ import annotations

import logging
import random
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st
from sqlalchemy import create_engine, insert, select, update

from server.database import Database, normalize_url
from server.mapcounts import Counts, count_rows, reconcile, walls_after_delta, walls_of_snapshot
from server.mapstore import apply_upload
from server.migrate import downgrade, upgrade
from server.models import MapState, Robot
from server.schemas import MapUpload
from shared.protocol import MAX_TRAJECTORY_POSES
from tests.server.live import Live
from tests.server.procs import fresh_database

_IDS = st.sets(st.integers(0, 60), max_size=40)


@given(stored=_IDS, sent=_IDS, removed=_IDS)
def test_walls_after_a_delta_are_the_set_arithmetic(
    stored: set[int], sent: set[int], removed: set[int]
) -> None:
    """Removed walls go, then sent walls are inserted or replaced: ``(stored - removed) | sent``."""
    up = MapUpload.model_validate(
        {
            "version": 2,
            "base_version": 1,
            "segments": [[i, 0.0, 0.0, 1.0, 1.0] for i in sorted(sent)],
            "removed": sorted(removed),
            "pose": [0, 0, 0],
        }
    )
    present = stored & (sent | removed)  # what the undo record's read finds among the touched ids
    assert walls_after_delta(len(stored), up, present) == len((stored - removed) | sent)


def test_a_snapshot_counts_its_distinct_walls() -> None:
    up = MapUpload.model_validate(
        {"version": 1, "base_version": None, "segments": [[3, 0, 0, 1, 1], [3, 0, 0, 2, 2], [4, 0, 0, 1, 1]]}
    )
    assert walls_of_snapshot(up) == 2


def _stored(live: Live, rid: int) -> tuple[Counts, Counts]:
    """(the counts in map_states, the rows counted)."""
    with live.state.db.read() as s:
        row = s.execute(select(MapState.n_walls, MapState.n_poses).where(MapState.robot_id == rid)).one()
        return Counts(int(row[0]), int(row[1])), count_rows(s.connection(), rid)


def _walls(rng: random.Random, ids: list[int]) -> list[list[float]]:
    return [
        [float(i), rng.uniform(-9, 9), rng.uniform(-9, 9), rng.uniform(-9, 9), rng.uniform(-9, 9)]
        for i in ids
    ]


def test_the_counts_follow_every_kind_of_upload(live: Live) -> None:
    rid, token = live.new_robot()
    rng = random.Random(7)
    session, version, stamp = str(uuid.uuid4()), 1, 0.0

    def poses(n: int) -> list[list[float]]:
        nonlocal stamp
        rows = [[stamp + 0.01 * j, 0.0, 0.0, 0.0] for j in range(n)]
        stamp += 0.01 * n
        return rows

    def post(body: dict[str, Any]) -> None:
        r = robot.post(f"/robots/{rid}/maps", json={"pose": [0, 0, 0], "map_session": session, **body})
        assert r.status_code == 200, r.text
        kept, counted = _stored(live, rid)
        assert kept == counted, body.get("base_version")

    with live.client(token) as robot:
        post(
            {
                "version": 1,
                "base_version": None,
                "segments": _walls(rng, [1, 2, 2, 3]),
                "trajectory": poses(3),
            }
        )
        for _ in range(25):
            ids = rng.sample(range(60), rng.randint(0, 15))
            gone = rng.sample(range(60), rng.randint(0, 8))  # stored ones, absent ones, some also sent
            body = {"version": version + 1, "base_version": version, "removed": gone}
            post(body | {"segments": _walls(rng, ids), "trajectory": poses(rng.randint(0, 40))})
            version += 1
        # past the trajectory's cap: thinned in the upload's transaction, the count follows
        for _ in range(2):
            big = poses(MAX_TRAJECTORY_POSES * 3 // 4)
            post({"version": version + 1, "base_version": version, "segments": [], "trajectory": big})
            version += 1
        kept, _ = _stored(live, rid)
        assert MAX_TRAJECTORY_POSES // 2 < kept.poses <= MAX_TRAJECTORY_POSES
        # a snapshot of the same session, then a new map session: each replaces the map
        version += 1
        post(
            {
                "version": version,
                "base_version": None,
                "segments": _walls(rng, [5, 6]),
                "trajectory": poses(2),
            }
        )
        session = str(uuid.uuid4())
        post({"version": 1, "base_version": None, "segments": _walls(rng, [7]), "trajectory": []})
    assert _stored(live, rid)[0] == Counts(1, 0)


def test_a_drift_is_found_corrected_and_logged(live: Live, caplog: pytest.LogCaptureFixture) -> None:
    rid, token = live.new_robot()
    with live.client(token) as robot:
        body = {"version": 1, "base_version": None, "segments": [[1, 0, 0, 1, 1]], "pose": [0, 0, 0]}
        assert robot.post(f"/robots/{rid}/maps", json=body).status_code == 200
    with live.state.db.write_conn() as conn:
        conn.execute(update(MapState).where(MapState.robot_id == rid).values(n_walls=40, n_poses=3))
        with caplog.at_level(logging.WARNING, logger="server.mapcounts"):
            assert reconcile(conn, rid, Counts(40, 3)) == Counts(1, 0)
        assert "40 walls and 3 poses, but 1 walls and 0 poses are stored" in caplog.text
        assert reconcile(conn, rid, Counts(1, 0)) == Counts(1, 0)
    assert _stored(live, rid) == (Counts(1, 0), Counts(1, 0))


@pytest.fixture(params=["sqlite", "postgresql"])
def database(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    with fresh_database(request.param, tmp_path) as url:
        yield normalize_url(url)


def test_the_migration_counts_the_rows_stored_before_it(database: str) -> None:
    engine = create_engine(database)
    upgrade(engine)
    db = Database(database)
    try:
        with db.write_conn() as conn:
            rid = int(
                conn.execute(
                    insert(Robot).values(name="m", token_hash="0" * 64).returning(Robot.id)
                ).scalar_one()
            )
            up = MapUpload.model_validate(
                {
                    "version": 1,
                    "base_version": None,
                    "segments": [[i, 0, 0, 1, 1] for i in range(5)],
                    "trajectory": [[0.1 * i, 0, 0, 0] for i in range(7)],
                    "pose": [0, 0, 0],
                }
            )
            apply_upload(conn, rid, up, "k", None, 20_000)
        downgrade(engine, "0011")  # the columns gone, the rows stay
        upgrade(engine)
        with db.write_conn() as conn:
            got = conn.execute(
                select(MapState.n_walls, MapState.n_poses).where(MapState.robot_id == rid)
            ).one()
        assert tuple(got) == (5, 7)
    finally:
        db.dispose()
        engine.dispose()
