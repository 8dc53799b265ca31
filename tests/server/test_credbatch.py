"""Cache misses that arrive together are answered by one read (server.credbatch): in-process with a
scripted read, and through the real server with a cold cache and many robots at once."""

from __future__ import annotations

import asyncio

import httpx
import pytest

from server.credbatch import LookupBatcher
from server.credcache import Kind, Principal
from tests.server.live import Live


class Reads:
    """A scripted ``resolve``: records each batch; answers robot ``h<i>`` with id ``i``; a read waits for
    ``gate`` so that requests can pile up behind it."""

    def __init__(self, fail: bool = False) -> None:
        self.batches: list[dict[Kind, list[str]]] = []
        self.gate = asyncio.Event()
        self.fail = fail

    async def __call__(self, batch: dict[Kind, list[str]]) -> dict[str, Principal | None]:
        self.batches.append(batch)
        await self.gate.wait()
        if self.fail:
            raise RuntimeError("database away")
        return {
            k: Principal("robot", int(k[1:]), k) for keys in batch.values() for k in keys if k[1:].isdigit()
        }


def test_misses_during_a_read_share_the_next_one_and_a_repeated_key_one_answer() -> None:
    async def go() -> None:
        reads = Reads()
        batcher = LookupBatcher(reads)
        first = asyncio.create_task(batcher.get("h1", "robot"))
        await asyncio.sleep(0)  # the first read begins with h1 alone
        asked: list[tuple[str, Kind]] = [("h2", "robot"), ("h2", "robot"), ("hx", "session"), ("h3", "robot")]
        rest = [asyncio.create_task(batcher.get(k, kind)) for k, kind in asked]
        await asyncio.sleep(0)
        reads.gate.set()
        got = await asyncio.gather(first, *rest)
        assert [None if p is None else p.id for p in got] == [1, 2, 2, None, 3]
        assert reads.batches == [{"robot": ["h1"]}, {"robot": ["h2", "h3"], "session": ["hx"]}]
        assert batcher.batches == 2

    asyncio.run(go())


def test_a_failed_read_reaches_every_request_that_waited_and_the_next_read_works() -> None:
    async def go() -> None:
        reads = Reads(fail=True)
        batcher = LookupBatcher(reads)
        waiting = [asyncio.create_task(batcher.get(f"h{i}", "robot")) for i in range(3)]
        await asyncio.sleep(0)
        reads.gate.set()
        for task in waiting:
            with pytest.raises(RuntimeError, match="database away"):
                await task
        reads.fail = False
        assert (await batcher.get("h7", "robot")) == Principal("robot", 7, "h7")

    asyncio.run(go())


def test_a_request_that_goes_away_leaves_the_others_their_answer() -> None:
    async def go() -> None:
        reads = Reads()
        batcher = LookupBatcher(reads)
        gone = asyncio.create_task(batcher.get("h4", "robot"))
        stays = asyncio.create_task(batcher.get("h4", "robot"))
        await asyncio.sleep(0)
        gone.cancel()
        reads.gate.set()
        assert (await stays) == Principal("robot", 4, "h4")
        assert gone.cancelled()

    asyncio.run(go())


def test_a_cold_cache_answers_many_robots_at_once_in_fewer_reads(live: Live) -> None:
    robots = [live.new_robot() for _ in range(20)]
    live.state.forget_credentials()
    before = live.state.lookups.batches

    async def go() -> list[int]:
        async with httpx.AsyncClient(base_url=live.base_url + "/api/v1", timeout=30.0) as client:
            answers = await asyncio.gather(
                *(
                    client.get(f"/robots/{rid}/maps", headers={"Authorization": f"Bearer {token}"})
                    for rid, token in robots
                ),
                client.get(
                    f"/robots/{robots[0][0]}/maps", headers={"Authorization": "Bearer lmr_not-a-token"}
                ),
            )
        return [r.status_code for r in answers]

    codes = asyncio.run(go())
    assert codes == [200] * 20 + [401]
    reads = live.state.lookups.batches - before
    assert 1 <= reads < 21  # the 21 misses of the burst shared reads
