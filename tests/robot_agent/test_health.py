"""``last_error`` has a time and is cleared once the robot is healthy again (robot_agent/health.py,
docs/reliability/agent.md). Repairing a stored configuration is in tests/robot_agent/test_recover.py."""

from __future__ import annotations

from robot_agent.health import AgentStats, ErrorReport


class _Clock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


def test_an_error_is_reported_with_its_time_then_cleared_after_a_healthy_spell() -> None:
    clock = _Clock()
    rep = ErrorReport(60.0, clock=clock, wall=lambda: 1_764_669_600.0)
    assert rep.status() is None
    rep.report("poll failed")
    assert rep.status() == "2025-12-02T10:00:00Z: poll failed"
    rep.healthy_round()
    rep.healthy_round()
    assert rep.message == "poll failed", "not cleared before clear_after_s"
    clock.t += 61.0
    rep.healthy_round()
    assert rep.message is None and rep.status() is None


def test_a_new_error_restarts_the_count_and_no_round_no_clear() -> None:
    clock = _Clock()
    rep = ErrorReport(10.0, clock=clock)
    rep.report("first")
    clock.t += 100.0
    assert rep.message == "first", "not cleared without a status reaching the server"
    rep.report("second")
    rep.healthy_round()
    rep.healthy_round()
    assert rep.message == "second"
    clock.t += 11.0
    rep.healthy_round()
    assert rep.message is None


def test_agent_stats_last_error_goes_through_the_report() -> None:
    stats = AgentStats(ErrorReport(0.0))
    stats.last_error = "rolled back: x"
    assert stats.last_error == "rolled back: x"
    assert (stats.errors.status() or "").endswith("Z: rolled back: x")
