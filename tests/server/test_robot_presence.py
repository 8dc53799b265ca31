"""A robot's online state survives wall-clock steps (docs/reliability/agent.md): this process's own "seen"
state is on the monotonic clock, and a stored ``last_seen_at`` in the future (the clock stepped back since
it was written) proves nothing. Pure function, then through uvicorn with a stepped-back clock simulated by
a future ``last_seen_at`` in the database."""

from __future__ import annotations

from collections.abc import Iterator
from datetime import UTC, datetime, timedelta
from pathlib import Path

import pytest
from hypothesis import assume, given
from hypothesis import strategies as st
from sqlalchemy import update

from server.deps import presence
from server.models import Robot, utcnow
from tests.server.live import Live, start_live

NOW = datetime(2026, 12, 2, 10, 0, tzinfo=UTC)
WINDOW_S = 10.0


def test_a_robot_seen_just_now_is_online() -> None:
    assert presence(NOW - timedelta(seconds=2), None, None, NOW, WINDOW_S) == (
        NOW - timedelta(seconds=2),
        True,
    )
    assert presence(None, NOW, 1.0, NOW, WINDOW_S)[1] is True


def test_a_future_stored_time_is_a_clock_step_not_online() -> None:
    an_hour_ahead = NOW + timedelta(hours=1)  # written before the clock stepped back one hour
    assert presence(an_hour_ahead, None, None, NOW, WINDOW_S)[1] is False
    # this process heard from it 30 s ago on the monotonic clock: offline, whatever the wall clock says
    assert presence(an_hour_ahead, an_hour_ahead, 30.0, NOW, WINDOW_S)[1] is False
    assert presence(an_hour_ahead, an_hour_ahead, 3.0, NOW, WINDOW_S)[1] is True


def test_a_clock_step_forward_does_not_hide_a_robot_heard_from() -> None:
    an_hour_ago = NOW - timedelta(hours=1)  # the clock jumped ahead since it was heard from
    assert presence(an_hour_ago, an_hour_ago, 2.0, NOW, WINDOW_S)[1] is True


@given(
    step_s=st.floats(min_value=-1e7, max_value=1e7, allow_nan=False),
    silent_s=st.floats(min_value=0.0, max_value=1e6, allow_nan=False),
)
def test_a_robot_this_process_heard_from_goes_offline_one_window_after_whatever_the_clock_did(
    step_s: float, silent_s: float
) -> None:
    """Seen at wall time T (stored and in memory); silent for ``silent_s`` (monotonic), during which the wall
    clock also moved by ``step_s``."""
    now = NOW + timedelta(seconds=silent_s + step_s)
    _, online = presence(NOW, NOW, silent_s, now, WINDOW_S)
    assert online == (silent_s <= WINDOW_S)


@given(
    step_s=st.floats(min_value=-1e7, max_value=1e7, allow_nan=False),
    silent_s=st.floats(min_value=0.0, max_value=1e6, allow_nan=False),
)
def test_a_robot_known_only_from_the_database_is_online_only_within_a_window_either_side(
    step_s: float, silent_s: float
) -> None:
    assume(abs(abs(silent_s + step_s) - WINDOW_S) > 1e-3)  # timedelta rounds to microseconds
    now = NOW + timedelta(seconds=silent_s + step_s)
    _, online = presence(NOW, None, None, now, WINDOW_S)
    assert online == (-WINDOW_S <= silent_s + step_s <= WINDOW_S)


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    yield from start_live("sqlite", tmp_path_factory.mktemp("presence"))


def test_after_the_clock_stepped_back_a_silent_robot_reads_offline(live: Live, tmp_path: Path) -> None:
    rid, _token = live.new_robot()
    with live.state.db.session() as s:  # seen "now" by a clock that was one hour ahead
        s.execute(update(Robot).where(Robot.id == rid).values(last_seen_at=utcnow() + timedelta(hours=1)))
    with live.operator() as op:
        robot = op.get(f"/robots/{rid}").json()
        assert robot["online"] is False, robot
        listed = next(r for r in op.get("/robots").json() if r["id"] == rid)
        assert listed["online"] is False


def test_a_robot_heard_from_reads_online(live: Live) -> None:
    rid, token = live.new_robot()
    with live.client(token) as robot:
        assert robot.get(f"/robots/{rid}/messages", params={"after": 0, "wait": 0}).status_code == 200
    with live.operator() as op:
        assert op.get(f"/robots/{rid}").json()["online"] is True
