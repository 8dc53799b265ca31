"""The upload's rows and round trips on PostgreSQL (server.pgrows), on the real database of the shared live
server: walls, poses and removals sent as one JSON or array parameter come back as the very same doubles,
in order; the lock-and-read pipeline answers as the separate reads did; a statement failing inside a
pipeline is raised as SQLAlchemy's error (what the writer's batch retry and the storage check catch) and
leaves nothing written. On SQLite the same uploads go through the multi-row statements, with the same
stored map (the property test runs on both backends)."""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from sqlalchemy import select, text
from sqlalchemy.exc import DBAPIError

from server import maphistory, maplog, pgrows
from server.mapcounts import Counts, count_rows
from server.maphistory import capture_undo
from server.mapstore import apply_upload
from server.models import MapSegment, TrajectoryPoint
from server.schemas import MapUpload
from tests.server.live import Live

_COORD = st.floats(min_value=-1000.0, max_value=1000.0, allow_nan=False, allow_infinity=False)


def _pg(live: Live) -> None:
    if live.state.db.is_sqlite:
        pytest.skip("PostgreSQL's statements")


def _walls(live: Live, rid: int) -> list[tuple[int, float, float, float, float, int]]:
    with live.state.db.read() as s:
        rows = s.execute(
            select(
                MapSegment.segment_id,
                MapSegment.x0_m,
                MapSegment.y0_m,
                MapSegment.x1_m,
                MapSegment.y1_m,
                MapSegment.version,
            )
            .where(MapSegment.robot_id == rid)
            .order_by(MapSegment.segment_id)
        ).all()
    return [tuple(r) for r in rows]  # type: ignore[misc]


def _poses(live: Live, rid: int) -> list[tuple[float, float, float, float]]:
    with live.state.db.read() as s:
        rows = s.execute(
            select(
                TrajectoryPoint.stamp_s, TrajectoryPoint.x_m, TrajectoryPoint.y_m, TrajectoryPoint.theta_rad
            )
            .where(TrajectoryPoint.robot_id == rid)
            .order_by(TrajectoryPoint.id)
        ).all()
    return [tuple(r) for r in rows]  # type: ignore[misc]


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    walls=st.dictionaries(st.integers(0, 2**40), st.tuples(_COORD, _COORD, _COORD, _COORD), max_size=40),
    poses=st.lists(st.tuples(_COORD, _COORD, _COORD, _COORD), max_size=20),
    data=st.data(),
)
def test_an_uploads_rows_are_stored_as_the_same_doubles_in_order(
    live: Live,
    walls: dict[int, tuple[float, float, float, float]],
    poses: list[tuple[float, float, float, float]],
    data: st.DataObject,
) -> None:
    rid, _ = live.new_robot()
    snap = MapUpload.model_validate(
        {
            "version": 1,
            "base_version": None,
            "segments": [[k, *v] for k, v in walls.items()],
            "pose": [0, 0, 0],
        }
    )
    removed = data.draw(st.lists(st.sampled_from(sorted(walls)), unique=True) if walls else st.just([]))
    moved = {k: (v[2], v[3], v[0], v[1]) for k, v in walls.items() if k not in removed}
    delta = MapUpload.model_validate(
        {
            "version": 2,
            "base_version": 1,
            "segments": [[k, *v] for k, v in moved.items()],
            "removed": removed,
            "trajectory": [list(p) for p in poses],
            "pose": [0, 0, 0],
        }
    )
    with live.state.db.write_conn() as conn:
        apply_upload(conn, rid, snap, "version-1", None, 20_000)
    with live.state.db.write_conn() as conn:
        apply_upload(conn, rid, delta, "version-2", None, 20_000)
    # a wall the delta sends again as stored is not written again: it keeps the version that wrote it
    assert _walls(live, rid) == [(k, *v, 1 if v == walls[k] else 2) for k, v in sorted(moved.items())]
    assert _poses(live, rid) == poses


def test_lock_and_read_answers_what_the_separate_reads_answer(live: Live) -> None:
    _pg(live)
    rid, _ = live.new_robot()
    up = MapUpload.model_validate(
        {
            "version": 7,
            "base_version": None,
            "segments": [[1, 0, 0, 1, 1], [2, 0, 0, 2, 2]],
            "pose": [0, 0, 0],
        }
    )
    with live.state.db.write_conn() as conn:
        before = pgrows.lock_and_read(conn, 1, rid, "k-7")
        apply_upload(conn, rid, up, "k-7", None, 20_000)
    assert before == pgrows.UploadReads((0, None), None, Counts(0, 0))
    with live.state.db.write_conn() as conn:
        after = pgrows.lock_and_read(conn, 1, rid, "k-7")
        other = pgrows.lock_and_read(conn, 1, rid, "k-8")
        missing = pgrows.lock_and_read(conn, 1, 2**31 - 1, "k-7")
    assert after == pgrows.UploadReads((7, None), (7, None), Counts(2, 0))
    assert other == pgrows.UploadReads((7, None), None, Counts(2, 0))
    assert missing.robot is None


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    walls=st.dictionaries(st.integers(0, 2**40), st.tuples(_COORD, _COORD, _COORD, _COORD), max_size=30),
    extra=st.lists(st.integers(0, 2**40), max_size=10),
    snapshot_base=st.booleans(),
)
def test_a_deltas_reads_in_the_locks_round_trip_equal_the_separate_reads(
    live: Live,
    walls: dict[int, tuple[float, float, float, float]],
    extra: list[int],
    snapshot_base: bool,
) -> None:
    """The undo record's walls, log flag and map state, read in the lock's pipeline, answer as
    :func:`server.maphistory.capture_undo`'s own reads (base logged as a snapshot, whose centroids the
    record then keeps, or as a delta); the stored counts read with the robot are the rows'."""
    _pg(live)
    rid, _ = live.new_robot()
    first: dict[str, Any] = {
        "version": 1,
        "base_version": None,
        "segments": [[k, *v] for k, v in walls.items()],
        "centroids": [[0.5, -0.25]],
        "trajectory": [[0.1 * i, 1.0, 2.0, 0.3] for i in range(4)],
        "pose": [1.5, -2.0, 0.25],
    }
    second = {**first, "version": 2, "base_version": 1, "segments": first["segments"][:3], "trajectory": []}
    with live.state.db.write_conn() as conn:
        apply_upload(conn, rid, MapUpload.model_validate(first), "version-1", None, 20_000)
    if not snapshot_base:  # the base version is a logged delta (its entry holds its body)
        with live.state.db.write_conn() as conn:
            applied = apply_upload(conn, rid, MapUpload.model_validate(second), "version-2", None, 20_000)
            assert applied.event is not None
            maplog.append(conn, rid, applied.event)
    base = 1 if snapshot_base else 2
    keys = sorted(walls)
    delta = MapUpload.model_validate(
        {
            "version": base + 1,
            "base_version": base,
            "segments": [[k, 0.0, 0.0, 1.0, 1.0] for k in keys[: len(keys) // 2] + extra],
            "removed": keys[len(keys) // 2 :],
            "pose": [0, 0, 0],
        }
    )
    probe = pgrows.DeltaProbe(maphistory.touched_ids(delta), base)
    with live.state.db.write_conn() as conn:
        reads = pgrows.lock_and_read(conn, 1, rid, "k", delta=probe)
        assert reads.undo is not None
        assert capture_undo(conn, rid, delta, reads.undo) == capture_undo(conn, rid, delta)
        assert reads.counts == count_rows(conn, rid)


def test_a_failing_statement_in_a_pipeline_is_sqlalchemys_error_and_writes_nothing(live: Live) -> None:
    _pg(live)
    rid, _ = live.new_robot()

    def write() -> None:
        with live.state.db.write_conn() as conn, pgrows.pipelined(conn):
            pgrows.upsert_segments(conn, [(rid, 1, 0.0, 0.0, 1.0, 1.0, 1)])
            pgrows.upsert_segments(conn, [(2**31 - 1, 1, 0.0, 0.0, 1.0, 1.0, 1)])  # no such robot: FK

    with pytest.raises(DBAPIError) as err:
        write()
    assert "foreign key" in str(err.value).lower()
    assert _walls(live, rid) == []
    with live.state.db.write_conn() as conn:  # the pool's connection is usable again
        assert conn.execute(text("SELECT 1")).scalar() == 1


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    floats=st.lists(st.floats(allow_nan=False, allow_infinity=False), max_size=50),
    ints=st.lists(st.integers(-(2**63), 2**63 - 1), max_size=50),
)
def test_array_text_reads_back_as_the_same_values(live: Live, floats: list[float], ints: list[int]) -> None:
    """Any finite double (subnormals, -0.0, the largest) and any bigint, through the text form the write
    statements send: the very same values come back."""
    _pg(live)
    with live.state.db.read() as s:
        got_f, got_i = (
            s.connection()
            .exec_driver_sql(
                "SELECT %s::float8[], %s::bigint[]", (pgrows.array_text(floats), pgrows.array_text(ints))
            )
            .one()
        )
    assert [float(x).hex() for x in got_f] == [x.hex() for x in floats]  # -0.0 keeps its sign
    assert list(got_i) == ints
