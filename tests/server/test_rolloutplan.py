"""The rollout state machine (server.rolloutplan) driven with plain data and a clock of the test's own."""

from __future__ import annotations

from collections import Counter
from dataclasses import replace
from datetime import UTC, datetime, timedelta

import pytest
from hypothesis import given
from hypothesis import strategies as st

from server.rolloutplan import Observation, Outcome, RobotRun, RolloutView, advance, assign_waves, stop

T0 = datetime(2026, 12, 5, 12, 0, tzinfo=UTC)
OLD = "radius-outlier@1.0.0"
NEW = "radius-outlier@1.1.0"


def _rollout(**kw: object) -> RolloutView:
    base = RolloutView(
        id=1,
        stage="noise-removal",
        name="radius-outlier",
        version="1.1.0",
        canaries=1,
        wave_size=3,
        max_failure_share=0.2,
        commit_window_s=60.0,
        ack_timeout_s=300.0,
        max_step_ratio=2.0,
    )
    return replace(base, **kw)  # type: ignore[arg-type]


class Fleet:
    """Simulated robots: what each has acknowledged and reports; ``tick`` advances the rollout."""

    def __init__(self, n: int, canaries: int = 1, wave_size: int = 3, **kw: object) -> None:
        rollout = _rollout(canaries=canaries, wave_size=wave_size, **kw)
        self.out = Outcome(rollout, assign_waves(list(range(1, n + 1)), canaries, wave_size))
        self.seen = {rid: Observation(active=OLD, step_ms=10.0) for rid in range(1, n + 1)}
        self.now = T0
        self.log: list[tuple[float, str, int | None]] = []

    def tick(self, dt_s: float = 0.0) -> Outcome:
        self.now += timedelta(seconds=dt_s)
        self.out = advance(self.out.rollout, self.out.robots, self.seen, self.now)
        for ev in self.out.events:
            self.log.append(((self.now - T0).total_seconds(), ev.action, ev.robot_id))
        return self.out

    def ack(self, rid: int, outcome: str, reason: str | None = None) -> None:
        self.seen[rid] = replace(self.seen[rid], ack=outcome, ack_reason=reason)

    def report(self, rid: int, **kw: object) -> None:
        self.seen[rid] = replace(self.seen[rid], **kw)  # type: ignore[arg-type]

    def robot(self, rid: int) -> RobotRun:
        return next(r for r in self.out.robots if r.robot_id == rid)

    def states(self) -> Counter[str]:
        return Counter(r.state for r in self.out.robots)

    def apply_healthy(self, rids: list[int]) -> None:
        for rid in rids:
            self.ack(rid, "applied")
            self.report(rid, active=NEW)


def test_waves_are_assigned_canaries_first() -> None:
    runs = assign_waves([7, 3, 9, 4, 5, 6], canaries=2, wave_size=3)
    assert [(r.robot_id, r.wave) for r in runs] == [(7, 0), (3, 0), (9, 1), (4, 1), (5, 1), (6, 2)]


def test_healthy_rollout_completes_in_waves() -> None:
    f = Fleet(10, canaries=1, wave_size=3)
    out = f.tick()
    assert out.sends == (1,), "only the canary goes first"
    assert f.robot(1).previous == OLD and f.robot(1).baseline_step_ms == 10.0
    f.apply_healthy([1])
    f.tick(1)
    assert f.robot(1).state == "applied"
    assert f.tick(30).sends == (), "the canary's window is not over"
    out = f.tick(31)
    assert f.robot(1).state == "installed" and out.sends == (2, 3, 4)
    for wave in ((2, 3, 4), (5, 6, 7), (8, 9, 10)):
        f.apply_healthy(list(wave))
        f.tick(1)
        f.tick(61)
    assert f.states() == Counter({"installed": 10})
    assert f.out.rollout.state == "completed" and not f.out.rollout.active
    waves = [e for e in f.log if e[1] == "rollout.wave"]
    assert len(waves) == 4


def test_failing_canary_stops_and_rolls_back_leaving_the_rest_untouched() -> None:
    f = Fleet(10)
    f.tick()
    f.ack(1, "applied")
    f.tick(1)
    f.ack(1, "rolled-back", "kernel raised in service: ZeroDivisionError")
    out = f.tick(1)
    assert out.rollout.state == "stopped"
    assert "canary robot 1 failed" in (out.rollout.stop_reason or "")
    assert "ZeroDivisionError" in (out.rollout.stop_reason or "")
    assert f.robot(1).state == "rolled-back" and "ZeroDivisionError" in (f.robot(1).reason or "")
    assert f.states() == Counter({"skipped": 9, "rolled-back": 1})
    assert out.sends == ()
    assert all(r.sent_at is None for r in out.robots if r.robot_id != 1), "nobody else got the update"


def test_canary_health_failure_sends_a_rollback_to_the_previous_version() -> None:
    f = Fleet(5, max_step_ratio=2.0)
    f.tick()
    f.ack(1, "applied")
    f.report(1, active=NEW, step_ms=25.0)  # 2.5 x its 10 ms before
    out = f.tick(1)
    assert out.rollbacks == ((1, OLD),)
    assert "2.50 x" in (f.robot(1).reason or "") and out.rollout.state == "stopped"


def test_new_rollback_error_fails_but_an_old_one_does_not() -> None:
    f = Fleet(2, canaries=1)
    f.report(1, last_error="rolled back: an older problem")
    f.tick()
    f.apply_healthy([1])
    f.tick(1)
    assert f.robot(1).state == "applied", "the error it had before is not the update's"
    f.report(1, last_error="rolled back: radius-outlier 1.1.0 overran its budget")
    f.tick(1)
    assert f.robot(1).state == "rolled-back" and "overran" in (f.robot(1).reason or "")


def test_stuck_robot_times_out_and_the_waves_go_on() -> None:
    f = Fleet(6, canaries=1, wave_size=5, max_failure_share=0.4)
    f.tick()
    f.apply_healthy([1])
    f.tick(1)
    f.tick(61)
    f.apply_healthy([2, 3, 4, 5])  # robot 6 never answers
    f.tick(1)
    f.tick(61)
    assert f.robot(6).state == "sent" and f.out.rollout.state == "running"
    f.tick(300)
    assert f.robot(6).state == "timed-out" and "no acknowledgement within 300 s" in (f.robot(6).reason or "")
    assert f.out.rollout.state == "completed", "1 of 6 failed is within 40 %"
    assert f.out.rollout.active, "the timed-out robot is watched"
    f.ack(6, "applied")
    out = f.tick(1)
    assert out.rollbacks == ((6, OLD),) and not out.rollout.active


def test_failure_share_over_the_limit_stops_the_later_waves() -> None:
    f = Fleet(10, canaries=1, wave_size=3, max_failure_share=0.2)
    f.tick()
    f.apply_healthy([1])
    f.tick(1)
    f.tick(61)
    f.apply_healthy([2, 3])
    f.ack(4, "rejected", "sha256 mismatch")
    out = f.tick(1)
    # 1 of 4 tried = 25 % > 20 %: stop; robots 2 and 3 (in their window) and 1 (committed) roll back
    assert out.rollout.state == "stopped" and "1 of 4 robots tried failed (25%" in (
        out.rollout.stop_reason or ""
    )
    assert sorted(out.rollbacks) == [(1, OLD), (2, OLD), (3, OLD)]
    assert f.robot(4).state == "failed" and "sha256 mismatch" in (f.robot(4).reason or "")
    assert [f.robot(r).state for r in range(5, 11)] == ["skipped"] * 6


@pytest.mark.parametrize(("failed", "tried", "limit", "stops"), [(1, 5, 0.2, False), (2, 5, 0.2, True)])
def test_threshold_is_strictly_more_than_the_share(
    failed: int, tried: int, limit: float, stops: bool
) -> None:
    done = [
        RobotRun(robot_id=i + 1, position=i, wave=1, state="failed" if i < failed else "installed")
        for i in range(tried)
    ]
    runs = (*done, RobotRun(robot_id=99, position=99, wave=2))
    out = advance(_rollout(max_failure_share=limit, wave=1), runs, {99: Observation(active=OLD)}, T0)
    assert (out.rollout.state == "stopped") is stops


@given(
    n=st.integers(1, 30),
    canaries=st.integers(1, 5),
    wave=st.integers(1, 8),
    fail=st.sets(st.integers(1, 30)),
)
def test_no_robot_is_sent_after_a_stop(n: int, canaries: int, wave: int, fail: set[int]) -> None:
    """Whatever fails: once stopped, nothing more is sent, and failed + skipped + rolled back + installed
    covers every robot; a canary failure always stops."""
    canaries = min(canaries, n)
    f = Fleet(n, canaries=canaries, wave_size=wave, max_failure_share=0.3, commit_window_s=10.0)
    sent_after_stop = 0
    for _ in range(4 * n + 4):
        out = f.tick(11)
        if out.rollout.state == "stopped":
            sent_after_stop += len(out.sends)
        for run in out.robots:
            if run.state == "sent":
                f.ack(run.robot_id, "rejected" if run.robot_id in fail else "applied", "bad")
                if run.robot_id not in fail:
                    f.report(run.robot_id, active=NEW)
        if not out.rollout.active:
            break
    assert sent_after_stop == 0
    assert set(f.states()) <= {"installed", "failed", "rolled-back", "skipped"}
    if any(r <= canaries for r in fail):
        assert f.out.rollout.state == "stopped"
    if not fail & set(range(1, n + 1)):
        assert f.out.rollout.state == "completed"


def test_pause_holds_the_next_wave_and_abort_rolls_back() -> None:
    f = Fleet(4, canaries=1, wave_size=3)
    f.tick()
    f.apply_healthy([1])
    f.tick(1)
    f.out = replace(f.out, rollout=replace(f.out.rollout, state="paused"))
    out = f.tick(61)
    assert f.robot(1).state == "installed", "robots in flight are still judged"
    assert out.sends == (), "no wave while paused"
    f.out = replace(f.out, rollout=replace(f.out.rollout, state="running"))
    assert f.tick(1).sends == (2, 3, 4)
    f.apply_healthy([2])
    f.tick(1)
    out = stop(f.out, "aborted by operator:admin", f.now, state="aborted")
    assert out.rollout.state == "aborted"
    assert sorted(out.rollbacks) == [(1, OLD), (2, OLD)]
    assert f.robot(3).state == "sent"
    f.out = out
    f.ack(3, "applied")
    f.ack(4, "rejected", "no")
    out = f.tick(1)
    assert out.rollbacks == ((3, OLD),), "a late apply after the abort is rolled back"
    assert not out.rollout.active


def test_robot_without_a_reported_kernel_is_not_updated() -> None:
    f = Fleet(2)
    f.seen[1] = Observation()
    out = f.tick()
    assert out.sends == () and out.rollout.state == "stopped"
    assert "has not reported its active noise-removal kernel" in (f.robot(1).reason or "")


def test_applied_but_never_reported_active_is_rolled_back() -> None:
    f = Fleet(1, ack_timeout_s=30.0)
    f.tick()
    f.ack(1, "applied")
    f.tick(1)
    f.tick(60)
    assert f.robot(1).state == "applied"
    out = f.tick(31)
    assert out.rollbacks == ((1, OLD),) and "not reported active" in (f.robot(1).reason or "")


def test_a_chain_is_updated_by_name_and_rolled_back_to_its_version() -> None:
    """Noise removal may be a chain ("a@1, b@2"): the update switches the kernel of its name; the robot
    commits when the chain reports the new version, and a rollback names the version it ran before."""
    f = Fleet(2, canaries=1, max_failure_share=0.5)
    f.report(1, active=f"dbscan@1.0.0, {OLD}")
    f.report(2, active="dbscan@1.0.0")
    out = f.tick()
    assert out.sends == (1,) and f.robot(1).previous == OLD
    f.ack(1, "applied")
    f.report(1, active=f"dbscan@1.0.0, {NEW}")
    f.tick(1)
    f.tick(61)
    assert f.robot(1).state == "installed"
    assert f.robot(2).state == "failed" and "runs no radius-outlier" in (f.robot(2).reason or "")
    assert f.robot(2).sent_at is None and f.out.rollout.state == "completed"
