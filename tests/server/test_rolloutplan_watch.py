"""The rollout state machine's watches: a committed robot stays judged while the rollout goes on, and a
timed-out robot is watched only until the rollout's ``watch_timeout_s`` (server.rolloutplan)."""

from __future__ import annotations

from collections import Counter

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests.server.test_rolloutplan import NEW, OLD, Fleet


def _commit(f: Fleet, rids: list[int]) -> None:
    f.apply_healthy(rids)
    f.tick(1)
    f.tick(61)


def test_a_committed_robot_failing_during_later_waves_counts_and_is_rolled_back() -> None:
    f = Fleet(7, canaries=1, wave_size=3, max_failure_share=0.2)
    f.tick()
    _commit(f, [1])
    _commit(f, [2, 3, 4])
    assert f.robot(2).state == "installed" and f.out.rollout.wave == 2
    f.report(2, step_ms=35.0)  # committed, then three and a half times slower while wave 2 runs
    out = f.tick(1)
    row = f.robot(2)
    assert row.state == "rolled-back" and (row.reason or "").startswith("after its commit, health: step time")
    assert (2, OLD) in out.rollbacks
    # 1 of 7 tried (1, 2-4, 5-7 sent) = 14 %: within 20 %, the rollout goes on
    assert out.rollout.state == "running"
    f.report(5, last_error="rolled back: radius-outlier 1.1.0 raised")
    f.ack(5, "applied")
    out = f.tick(1)
    assert out.rollout.state == "stopped" and "2 of 7 robots tried failed" in (out.rollout.stop_reason or "")


def test_a_committed_canary_rolled_back_by_its_own_guard_stops_the_rollout() -> None:
    f = Fleet(5, canaries=1, wave_size=2)
    f.tick()
    _commit(f, [1])
    f.ack(1, "rolled-back", "radius-outlier 1.1.0 took 694.7 ms, over its 200 ms budget")
    f.report(1, active=OLD)
    out = f.tick(1)
    assert f.robot(1).state == "rolled-back" and "694.7 ms" in (f.robot(1).reason or "")
    assert out.rollout.state == "stopped" and "canary robot 1 failed: after its commit" in (
        out.rollout.stop_reason or ""
    )
    assert (1, OLD) not in out.rollbacks, "its guard put the previous kernel back already"
    assert [f.robot(r).state for r in (4, 5)] == ["skipped", "skipped"]


def test_committed_robots_are_not_judged_after_the_rollout_completed() -> None:
    f = Fleet(4, canaries=1, wave_size=3)
    f.tick()
    _commit(f, [1])
    _commit(f, [2, 3, 4])
    assert f.out.rollout.state == "completed" and not f.out.rollout.active
    f.report(3, step_ms=100.0)
    out = f.tick(1)
    assert f.robot(3).state == "installed" and out.rollbacks == () and out.events == ()


def test_a_robot_that_already_ran_the_version_is_not_judged() -> None:
    f = Fleet(3, canaries=1, wave_size=2)
    f.report(2, active=NEW, step_ms=10.0)
    f.tick()
    _commit(f, [1])
    assert f.robot(2).state == "installed" and "already running" in (f.robot(2).reason or "")
    f.report(2, step_ms=90.0)
    f.tick(1)
    assert f.robot(2).state == "installed", "nothing to compare with, nothing to roll back to"


def test_a_timed_out_robot_is_given_up_at_the_watch_deadline_and_the_rollout_finishes() -> None:
    f = Fleet(3, canaries=1, wave_size=2, max_failure_share=0.5, ack_timeout_s=300.0, watch_timeout_s=900.0)
    f.tick()
    _commit(f, [1])
    f.apply_healthy([2])  # robot 3 never answers
    f.tick(1)
    f.tick(61)
    f.tick(300)
    row = f.robot(3)
    assert row.state == "timed-out" and row.watch
    assert "watched for a late answer until 900 s" in (row.reason or "")
    assert f.out.rollout.state == "completed" and f.out.rollout.active
    assert f.tick(500).rollbacks == () and f.out.rollout.active, "not yet 900 s after it was sent"
    out = f.tick(100)
    row = f.robot(3)
    assert row.state == "timed-out" and not row.watch
    assert "no answer within 900 s: no longer watched" in (row.reason or "")
    assert out.rollbacks == ((3, OLD),), "queued behind its update: it goes back if it ever applies it"
    assert not out.rollout.active
    assert [e[1:] for e in f.log if e[1] == "rollout.robot.unwatched"] == [("rollout.robot.unwatched", 3)]


@pytest.mark.parametrize("late", ["rejected", "rolled-back"])
def test_a_late_refusal_ends_the_watch_and_keeps_it_timed_out(late: str) -> None:
    f = Fleet(2, canaries=1, wave_size=1, max_failure_share=0.6, ack_timeout_s=10.0)
    f.tick()
    _commit(f, [1])
    f.tick(11)
    assert f.robot(2).state == "timed-out" and f.robot(2).watch
    f.ack(2, late, "no space left")
    out = f.tick(1)
    assert f.robot(2).state == "timed-out" and not f.robot(2).watch
    assert f"answered later: {late} (no space left)" in (f.robot(2).reason or "")
    assert out.rollbacks == () and not out.rollout.active


def test_a_timed_out_canary_stops_the_rollout() -> None:
    f = Fleet(4, canaries=1, wave_size=3, ack_timeout_s=5.0)
    f.tick()
    out = f.tick(5)
    assert f.robot(1).state == "timed-out"
    assert out.rollout.state == "stopped" and "canary robot 1 failed: no acknowledgement" in (
        out.rollout.stop_reason or ""
    )
    assert f.states() == Counter({"timed-out": 1, "skipped": 3})


@given(silent=st.sets(st.integers(1, 12)), steps=st.lists(st.floats(0.5, 400.0), min_size=1, max_size=40))
def test_a_rollout_always_ends_when_robots_never_answer(silent: set[int], steps: list[float]) -> None:
    """Whoever stays silent, and however the clock moves: once the watch deadline has passed after the
    last send, the rollout is no longer active, and every silent robot that was sent the update is
    timed-out with a rollback queued behind it."""
    f = Fleet(12, canaries=2, wave_size=4, max_failure_share=0.5, ack_timeout_s=60.0, watch_timeout_s=600.0)
    rolled: set[int] = set()
    for dt in [*steps, *[700.0] * 12]:  # then long enough for every wave and every watch to end
        out = f.tick(dt)
        rolled |= {rid for rid, _ in out.rollbacks}
        for run in out.robots:
            if run.state == "sent" and run.robot_id not in silent:
                f.ack(run.robot_id, "applied")
                f.report(run.robot_id, active=NEW)
    assert not f.out.rollout.active
    for run in f.out.robots:
        assert not run.watch
        if run.robot_id in silent and run.sent_at is not None:
            assert run.state in ("timed-out", "rolled-back") and run.robot_id in rolled
