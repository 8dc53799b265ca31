"""A flood of long-polls with a bad token: how long the robot's own poll and upload take meanwhile.

An attacker (or a misconfigured fleet: robots with a revoked token) opens ``--flood`` long-polls for
messages (``GET /robots/{id}/messages?wait=20``) with a token the server does not know, all at once, from
one address. The failed-authentication limit blocks that address after a few 401s; the polls that arrived
before the block were already admitted past it and wait at the long-polls' door (server.admission). The
figure of merit is what the real robot sees meanwhile: its own polls (``wait=0.01``: an answer within
10 ms when the server has time) and map uploads, one after the other at 10 Hz while the flood lasts,
each timed to its answer. The flood comes from its own process, as an attacker's would.

Each round floods from a different address (``X-Forwarded-For`` with ``LINEMAP_TRUSTED_PROXIES`` set to
127.0.0.1), so every round meets an address that is not yet blocked. Starts ``linemap server`` on a SQLite
temp file (``--db`` for another database). Prints per round and the medians. Exit 0 when it ran (figures,
not pass/fail), 2 when the setup failed.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import multiprocessing
import os
import statistics
import sys
import tempfile
import time
from collections import Counter
from multiprocessing.queues import Queue
from pathlib import Path

import httpx

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from benchmarks.server_load import STATUS, Server, SetupError

__all__ = ["main"]

API = "/api/v1"
PERIOD_S = 0.1  # the robot polls and uploads at the sensor's 10 Hz


async def _flood(base: str, rid: int, flood: int, address: str, token: bool) -> tuple[Counter[int], float]:
    """``flood`` long-polls at once, with a bad token or (``token`` False) none; (their status codes,
    seconds until the last answer)."""
    limits = httpx.Limits(max_connections=flood + 10, max_keepalive_connections=0)
    bad = {"X-Forwarded-For": address}
    if token:
        bad["Authorization"] = "Bearer lmr_bogus_token_from_nowhere"
    url = f"{base}{API}/robots/{rid}/messages"
    async with httpx.AsyncClient(limits=limits, timeout=120) as attacker:
        t0 = time.perf_counter()
        tasks = [attacker.get(url, params={"wait": 20}, headers=bad) for _ in range(flood)]
        answers = await asyncio.gather(*tasks, return_exceptions=True)
        end_s = time.perf_counter() - t0
    return Counter(a.status_code if isinstance(a, httpx.Response) else 0 for a in answers), end_s


def _attacker(
    base: str, rid: int, flood: int, address: str, token: bool, out: Queue[tuple[Counter[int], float]]
) -> None:
    out.put(asyncio.run(_flood(base, rid, flood, address, token)))


def _round(
    base: str, rid: int, token: str, flood: int, address: str, version: int, bad_token: bool = True
) -> tuple[list[float], list[float], Counter[int], float, int]:
    """One flood from its own process; meanwhile the robot polls (``wait=0.01``) and uploads, one after the
    other at 10 Hz, until the flood is answered. (its polls' ms, its uploads' ms, the flood's status codes,
    the flood's duration in s, the robot's last version)."""
    good = {"Authorization": f"Bearer {token}"}
    polls: list[float] = []
    uploads: list[float] = []
    ctx = multiprocessing.get_context("spawn")
    out: Queue[tuple[Counter[int], float]] = ctx.Queue()
    attacker = ctx.Process(target=_attacker, args=(base, rid, flood, address, bad_token, out))
    with httpx.Client(base_url=f"{base}{API}/robots/{rid}", headers=good, timeout=120) as robot:
        robot.get("/messages", params={"wait": 0.01}).raise_for_status()  # connected before the flood
        attacker.start()
        tick = time.perf_counter()
        while attacker.is_alive() and out.empty():
            tick += PERIOD_S
            time.sleep(max(0.0, tick - time.perf_counter()))
            t = time.perf_counter()
            r = robot.get("/messages", params={"wait": 0.01})
            assert r.status_code == 200, r.text
            polls.append((time.perf_counter() - t) * 1000)
            version += 1
            body = {
                "version": version,
                "base_version": None,
                "stamp_s": float(version),
                "segments": [[float(i), 0.0, float(i), 1.0, float(i)] for i in range(50)],
                "removed": [],
                "centroids": [],
                "trajectory": [[float(version), 0.0, 0.0, 0.0]],
                **STATUS,
            }
            t = time.perf_counter()
            r = robot.post("/maps", json=body)
            assert r.status_code in (200, 201), r.text
            uploads.append((time.perf_counter() - t) * 1000)
        codes, end_s = out.get(timeout=300)
        attacker.join()
    return polls, uploads, codes, end_s, version


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--db", help="database URL [a SQLite temp file]")
    p.add_argument("--flood", type=int, default=500, help="bad-token long-polls per round [500]")
    p.add_argument("--rounds", type=int, default=5, help="rounds, each from a new address [5]")
    p.add_argument("--no-token", action="store_true", help="the flood sends no credential at all")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(message)s")
    with tempfile.TemporaryDirectory(prefix="linemap-flood-") as tmp:
        db = args.db or f"sqlite:///{Path(tmp) / 'server.db'}"
        os.environ["LINEMAP_TRUSTED_PROXIES"] = "127.0.0.1"
        server = Server(db, 0, Path(tmp))
        try:
            admin = server.start()
            with httpx.Client(base_url=server.base + API, headers={"Authorization": f"Bearer {admin}"}) as op:
                r = op.post("/robots", json={"name": f"flood-{os.getpid()}"}).raise_for_status().json()
            rid, token = int(r["id"]), str(r["token"])
            worst_poll, worst_upload, version = [], [], 0
            for k in range(args.rounds):
                polls, uploads, codes, end_s, version = _round(
                    server.base, rid, token, args.flood, f"198.51.100.{k + 1}", version, not args.no_token
                )
                worst_poll.append(max(polls))
                worst_upload.append(max(uploads))
                print(
                    f"round {k + 1}: flood of {args.flood} answered {dict(sorted(codes.items()))} within "
                    f"{end_s:.2f} s; meanwhile the robot's {len(polls)} polls median "
                    f"{statistics.median(polls):.0f} ms, worst {max(polls):.0f} ms; its uploads median "
                    f"{statistics.median(uploads):.0f} ms, worst {max(uploads):.0f} ms",
                    flush=True,
                )
            print(
                f"median of {args.rounds} rounds: the robot's worst poll {statistics.median(worst_poll):.0f} "
                f"ms, worst upload {statistics.median(worst_upload):.0f} ms"
            )
        except SetupError as e:
            print(f"setup failed: {e}", file=sys.stderr)
            return 2
        finally:
            server.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
