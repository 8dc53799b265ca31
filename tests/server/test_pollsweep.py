"""The long-polls' safety net (server.pollsweep): one read for every waiting poll, and only the polls whose
robot has a message they have not seen are woken. Unit tests with an in-process reader; then a real server
whose hub never hears of a message written straight into its database: the waiting poll still gets it."""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import update

from server.hub import Hub
from server.models import Message, Robot
from server.pollsweep import PollSweep, message_topic
from tests.server.live import BACKENDS, Live, start_live


def test_one_read_wakes_only_the_polls_that_missed_a_message() -> None:
    async def go() -> None:
        hub = Hub()
        calls: list[list[int]] = []

        def read(ids: list[int]) -> dict[int, int]:
            calls.append(ids)
            return {1: 4, 2: 7}  # robot 3 has no row (deleted)

        sweep = PollSweep(hub, read)
        with (
            hub.subscribe(message_topic(1)) as q1,
            hub.subscribe(message_topic(2)) as q2,
            hub.subscribe(message_topic(3)) as q3,
            sweep.watch(1, 4),  # has seen message 4: nothing new
            sweep.watch(2, 7),
            sweep.watch(2, 5),  # an older poll of robot 2 waits after 5: messages 6 and 7 are new to it
            sweep.watch(3, 0),
        ):
            assert sweep.waiting() == {1: 4, 2: 5, 3: 0}
            assert await sweep.sweep() == 2
            assert calls == [[1, 2, 3]]  # one read for every waiting poll
            assert q1.empty()
            assert q2.get_nowait() == 7
            assert q3.get_nowait() is None  # deleted: woken, its read then answers 404
        assert sweep.waiting() == {}
        assert await sweep.sweep() == 0
        assert calls == [[1, 2, 3]]  # nobody waits: no read

    asyncio.run(go())


def test_watch_counts_polls_of_one_robot_with_the_same_number() -> None:
    sweep = PollSweep(Hub(), lambda ids: {})
    with sweep.watch(5, 2):
        with sweep.watch(5, 2):
            assert sweep.waiting() == {5: 2}
        assert sweep.waiting() == {5: 2}  # the other poll still waits
    assert sweep.waiting() == {}


@pytest.fixture(scope="module", params=BACKENDS)
def quick(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    """A server whose safety net runs every 0.2 s."""
    tmp: Path = tmp_path_factory.mktemp(f"pollsweep-{request.param}")
    yield from start_live(request.param, tmp, poll_recheck_s=0.2)


def test_a_message_the_hub_never_announced_reaches_the_waiting_poll(quick: Live) -> None:
    """A message written into the database by something that did not tell the hub (the case the safety net
    is for: a wake-up lost): the poll waiting up to 20 s answers it, woken by the sweep."""
    rid, token = quick.new_robot()
    result: dict[str, Any] = {}

    def poll() -> None:
        with quick.client(token) as robot:
            result["r"] = robot.get(f"/robots/{rid}/messages", params={"after": 0, "wait": 20})

    t = threading.Thread(target=poll)
    t.start()
    _wait_until(lambda: rid in quick.state.polls.waiting())
    woken_before = quick.state.polls.woken
    with quick.state.db.session() as s:  # no hub.publish / announce: only the sweep can find it
        s.add(
            Message(
                robot_id=rid,
                seq=1,
                xml="<xml><message><mode>offline</mode></message></xml>",
                created_by="test",
            )
        )
        s.execute(update(Robot).where(Robot.id == rid).values(last_seq=1))
    t.join(30)
    assert not t.is_alive()
    assert result["r"].status_code == 200, result["r"].text
    assert [m["seq"] for m in result["r"].json()["messages"]] == [1]
    assert quick.state.polls.woken > woken_before
    assert rid not in quick.state.polls.waiting()  # the poll is no longer counted once answered


def test_a_poll_with_nothing_new_is_not_woken_by_the_sweep(quick: Live) -> None:
    """The sweep runs five times during this 1 s poll; the robot's numbering does not move, so the poll is
    never woken and answers empty at its deadline."""
    rid, token = quick.new_robot()
    woken_before = quick.state.polls.woken
    with quick.client(token) as robot:
        got = robot.get(f"/robots/{rid}/messages", params={"after": 0, "wait": 1.0}).json()
    assert got["messages"] == [] and got["last_seq"] == 0
    assert quick.state.polls.woken == woken_before


def _wait_until(cond: Any) -> None:
    import time

    deadline = time.monotonic() + 10
    while not cond():  # readiness wait, not a timing assertion
        assert time.monotonic() < deadline, "the poll never started waiting"
        time.sleep(0.01)
