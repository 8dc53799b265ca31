"""Whatever the network answers, a real agent process keeps all its threads (docs/reliability/agent.md):
503 with ``Retry-After: inf`` / ``86400`` / garbage, a redirect, JSON of the wrong shape, a body that is
not JSON, and 30 s of a Wi-Fi login portal answering ``200 text/html`` to everything. Once the network is
good again, a message queued afterwards is applied and map versions keep arriving; ``last_error`` shows
the problem with its time and is cleared once the robot is healthy again. In-process: a loop that dies
from an unexpected exception is restarted and reported."""

from __future__ import annotations

import re
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from robot_agent.agent import Agent, AgentSettings
from robot_agent.link import PollAnswer, ServerLink
from tests.robot_agent.agentproc import AgentProcess, wait_for
from tests.robot_agent.answerproxy import AnswerProxy
from tests.server.live import Live, start_live

XML = {"Content-Type": "application/xml"}
EPSILON = "<xml><message><noise-removal><dbscan><epsilon>7</epsilon></dbscan></noise-removal></message></xml>"
BAD = b'<xml><message><kernel-rollback stage="noise-removal" name="dbscan" version="9.9.9"/></message></xml>'
STAMPED = re.compile(r"^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ: ")


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    yield from start_live("sqlite", tmp_path_factory.mktemp("hostile-net"), poll_recheck_s=1.0)


def _robot(op: httpx.Client, rid: int) -> dict[str, Any]:
    data: dict[str, Any] = op.get(f"/robots/{rid}").json()
    return data


def _status(op: httpx.Client, rid: int, seq: int) -> str:
    return str(op.get(f"/robots/{rid}/messages/{seq}").json()["status"])


def test_agent_threads_survive_every_hostile_answer(live: Live, tmp_path: Path) -> None:
    rid, token = live.new_robot()
    op = live.operator()
    with AnswerProxy(live.base_url) as proxy:
        agent = AgentProcess(
            tmp_path / "robot.db",
            server=proxy.url,
            robot_id=rid,
            token=token,
            extra=[
                "--rate",
                "20",
                "--laps",
                "0",
                "--retry-base",
                "0.05",
                "--retry-cap",  # tries keep coming through a minute of faults (30 s apart by default)
                "1",
                "--max-retry-after",
                "2",
                "--error-clear",
                "3",
            ],
        )
        try:
            wait_for("first map", lambda: _robot(op, rid)["map_version"] > 0, 120)
            for mode in ("503-inf", "503-day", "503-garbage", "redirect", "shape", "notjson"):
                proxy.mode = mode
                wait_for(
                    f"{mode}: polls and uploads met it",
                    lambda m=mode: proxy.count(m, "poll") >= 2 and proxy.count(m, "upload") >= 2,  # type: ignore[misc]
                    90,
                )
            proxy.mode = "portal"
            portal_until = time.monotonic() + 10.0
            wait_for(
                "10 s of a login portal",
                lambda: (
                    time.monotonic() >= portal_until
                    and proxy.count("portal", "poll") >= 3
                    and proxy.count("portal", "upload") >= 3
                ),
                90,
            )
            assert agent.proc.poll() is None, agent.output()
            proxy.mode = "pass"
            before = _robot(op, rid)["map_version"]
            r = op.post(f"/robots/{rid}/messages", content=EPSILON, headers=XML)
            assert r.status_code == 201, r.text
            seq = r.json()["seq"]
            wait_for("the message queued after is applied", lambda: _status(op, rid, seq) == "applied", 120)
            wait_for("map versions keep arriving", lambda: _robot(op, rid)["map_version"] > before + 20, 120)
            wait_for(
                "the new setting in force",
                lambda: (
                    (_robot(op, rid)["config"] or {})
                    .get("noise_removal", [{}])[0]
                    .get("params", {})
                    .get("epsilon_m")
                    == 0.07
                ),
            )
            # 9h: an error is shown with its time while it is recent, then cleared on a healthy robot.
            wait_for("last_error cleared once healthy", lambda: _robot(op, rid)["last_error"] is None, 60)
            r = op.post(f"/robots/{rid}/messages", content=BAD, headers=XML)
            bad = r.json()["seq"]
            shown = wait_for(
                "the rejection shown as last_error",
                lambda: (e := _robot(op, rid)["last_error"]) and f"message {bad} rejected" in e and e,
                60,
            )
            assert STAMPED.match(shown), shown
            wait_for("and cleared again", lambda: _robot(op, rid)["last_error"] is None, 60)
            assert _robot(op, rid)["online"] is True
        finally:
            assert agent.stop() == 0, agent.output()
    out = agent.output()
    assert "died" not in out and "Traceback" not in out, out[-3000:]
    assert "unexpected answer" in out and "text/html" in out, out[-3000:]  # the portal was a link fault


class _Flaky(ServerLink):
    """A real link whose poll and upload each raise an unexpected exception once (a bug in the loop)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.raised: set[str] = set()

    def poll_answer(self, after: int, wait_s: float) -> PollAnswer:
        if "poll" not in self.raised:
            self.raised.add("poll")
            raise KeyError("seq")
        return super().poll_answer(after, wait_s)


def test_a_dead_poller_is_restarted_and_reported(live: Live, tmp_path: Path) -> None:
    rid, token = live.new_robot()
    op = live.operator()
    settings = AgentSettings(
        source="sim",
        db_path=tmp_path / "robot.db",
        server_urls=(live.base_url,),
        robot_id=rid,
        token=token,
        rate_hz=20,
        laps=0,
        retry_base_s=0.05,
        poll_wait_s=2.0,
    )
    agent = Agent(settings, link=_Flaky(live.base_url, rid, token))
    stop = threading.Event()
    runner = threading.Thread(target=agent.run, args=(stop,))
    runner.start()
    try:
        wait_for(
            "the poller restarted",
            lambda: agent.threads.get("poller") and agent.threads["poller"].restarts == 1,
        )
        wait_for(
            "its death reported to the server",
            lambda: "thread poller died and was restarted: KeyError" in (_robot(op, rid)["last_error"] or ""),
            120,
        )
        r = op.post(f"/robots/{rid}/messages", content=EPSILON, headers=XML)
        seq = r.json()["seq"]
        wait_for("the restarted poller fetches messages", lambda: _status(op, rid, seq) == "applied", 120)
        assert agent.threads["poller"].is_alive() and agent.threads["uploader"].is_alive()
    finally:
        stop.set()
        runner.join(60)
    assert not runner.is_alive()
