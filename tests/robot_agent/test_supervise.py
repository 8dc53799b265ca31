"""The supervisor: a loop killed by an unexpected exception is restarted after a backoff and reported;
one that returns is done; a fatal error ends it and is kept (docs/reliability/agent.md)."""

from __future__ import annotations

import threading

import pytest

from robot_agent.errors import SourceError
from robot_agent.supervise import Supervised, run_supervised, supervise
from tests.robot_agent.agentproc import wait_for


def test_a_killed_thread_is_restarted_and_reported() -> None:
    stop = threading.Event()
    runs: list[int] = []
    deaths: list[tuple[str, str]] = []
    alive = threading.Event()

    def loop(stop: threading.Event) -> None:
        runs.append(1)
        if len(runs) <= 3:
            raise RuntimeError(f"injected death {len(runs)}")
        alive.set()
        stop.wait()

    sup = supervise("worker", loop, stop, lambda n, e: deaths.append((n, str(e))), retry_base_s=0.01)
    try:
        wait_for("the fourth run", alive.is_set, 30)
        assert sup.restarts == 3 and sup.is_alive()
        assert deaths == [("worker", f"injected death {i}") for i in (1, 2, 3)]
    finally:
        stop.set()
        sup.join(10)
    assert not sup.is_alive()


def test_a_failing_report_does_not_kill_the_supervisor() -> None:
    stop = threading.Event()
    runs: list[int] = []

    def loop(stop: threading.Event) -> None:
        runs.append(1)
        if len(runs) == 1:
            raise ValueError("boom")

    def report(_name: str, _exc: BaseException) -> None:
        raise OSError("log disk full")

    sup = supervise("worker", loop, stop, report, retry_base_s=0.01)
    sup.join(30)
    assert runs == [1, 1] and sup.restarts == 1 and not sup.is_alive()


def test_a_fatal_error_ends_supervision_and_is_kept() -> None:
    sup = Supervised("mapping")

    def loop(_stop: threading.Event) -> None:
        raise SourceError("no laser on /dev/ttyACM0")

    with pytest.raises(SourceError):
        run_supervised(sup, loop, threading.Event(), lambda n, e: None, fatal=(SourceError,))
    assert isinstance(sup.fatal_error, SourceError) and sup.restarts == 0


def test_stop_during_the_backoff_ends_the_loop() -> None:
    stop = threading.Event()
    sup = Supervised("uploader")

    def loop(stop: threading.Event) -> None:
        stop.set()
        raise RuntimeError("dies as the agent stops")

    run_supervised(sup, loop, stop, lambda n, e: None, retry_base_s=60.0)
    assert sup.restarts == 1
