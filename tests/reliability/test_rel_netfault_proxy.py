"""Network faults (docs/reliability.md): the agent talks to the server through :class:`FaultProxy`, which
drops, delays, duplicates and cuts 30 % of requests and responses (seeded). The agent maps a simulated
patrol at a steady pace (one small upload per step while the link keeps up); control messages, one of them
a kernel install, are queued during the run. At the end (faults off, the agent caught up and stopped) the
server holds every map version exactly once and in order, and every message was applied exactly once.

The proxy itself is tested first: each fault does what it says to a real request.

Fast part: ``UPLOADS`` uploads through the proxy. Soak (``-m soak``): ``LINEMAP_SOAK_UPLOADS`` (10,000).
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from tests.reliability.crashtools import (
    Rig,
    check_final,
    read_robot_db,
    server_messages,
    upload_records,
    write_figures,
)
from tests.reliability.netproxy import FAULTS, FaultProxy
from tests.robot_agent.agentproc import robot_db_meta, wait_for
from tests.server.live import Live, start_live

UPLOADS = 500
SOAK_UPLOADS = int(os.environ.get("LINEMAP_SOAK_UPLOADS", "10000"))
FAULT_RATE = 0.3
SEED = int(os.environ.get("LINEMAP_NETFAULT_SEED", "9"))
RATE_HZ = os.environ.get("LINEMAP_NETFAULT_RATE_HZ", "50")  # steps per second of the agent
MESSAGES = 10
KERNEL_AT = (3, 6, 9)  # which of the messages are kernel installs (the others set n-smax)


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    yield from start_live("sqlite", tmp_path_factory.mktemp("netfault-server"), poll_recheck_s=1.0)


def _proxy(live: Live, **kwargs: Any) -> FaultProxy:
    host, port = live.base_url.rsplit("//", 1)[1].split(":")
    return FaultProxy(host, int(port), **kwargs)


def _upload(client: httpx.Client, rid: int, version: int, key: str) -> httpx.Response:
    body = {"version": version, "base_version": None, "segments": [[1, 0, 0, 1, 0]], "pose": [0, 0, 0]}
    return client.post(f"/robots/{rid}/maps", json=body, headers={"Idempotency-Key": key})


@pytest.mark.parametrize("fault", FAULTS)
def test_each_fault_does_what_it_says(live: Live, fault: str) -> None:
    rid, token = live.new_robot()
    with _proxy(live, seed=1, fault_rate=1.0, faults=(fault,), delay_s=(0.05, 0.05)) as proxy:
        client = httpx.Client(
            base_url=proxy.url + "/api/v1", headers={"Authorization": f"Bearer {token}"}, timeout=30
        )
        with client:
            if fault in ("drop", "cut"):
                with pytest.raises(httpx.TransportError):
                    _upload(client, rid, 1, "k1")
            else:
                r = _upload(client, rid, 1, "k1")
                assert r.status_code == 200, r.text
                assert r.json()["version"] == 1
        counts = proxy.snapshot()
        # The client sees the second copy's answer: the server recognised the retry. (When both copies go
        # at once, which one the server takes second is a race: either answer is right then.)
        if fault in ("delay", "duplicate") and not counts.get("upload.duplicate.concurrent"):
            assert r.json() == {"version": 1, "duplicate": fault == "duplicate"}
    records = upload_records(live, rid)
    assert counts["upload.received"] == 1 and counts[f"upload.{fault}"] == 1
    if fault == "drop":
        assert records == [] and counts.get("upload.forwarded", 0) == 0, "a dropped request never arrives"
    else:
        assert records == [(1, None)], "applied once, whatever the fault"
        assert counts["upload.forwarded"] == (2 if fault == "duplicate" else 1)
    assert counts.get("upload.delivered", 0) == (0 if fault in ("drop", "cut") else 1)


def test_the_proxy_passes_requests_through_when_faults_are_off(live: Live) -> None:
    rid, token = live.new_robot()
    with _proxy(live, fault_rate=0.0) as proxy:
        with httpx.Client(
            base_url=proxy.url + "/api/v1", headers={"Authorization": f"Bearer {token}"}, timeout=30
        ) as client:
            for v in range(1, 21):  # one keep-alive connection, many requests
                assert _upload(client, rid, v, f"k{v}").json() == {"version": v, "duplicate": False}
            r = client.get(f"/robots/{rid}/messages", params={"after": 0})
            assert r.status_code == 200 and r.json()["messages"] == []
        counts = proxy.snapshot()
    assert counts["upload.delivered"] == 20 and counts["poll.delivered"] == 1
    assert counts["connections"] == 1
    assert not any(k.startswith("faults.") for k in counts)


def test_a_kernel_install_survives_failed_downloads(live: Live, tmp_path: Path) -> None:
    """The kernel's download is cut, then dropped, then goes through: the install is applied, not
    rejected for a network fault the next attempt does not meet."""
    with _proxy(live, fault_rate=0.0, script={"kernel": ["cut", "drop"]}) as proxy:
        rig = Rig(live, tmp_path / "robot.db", proxy.url, rate="20", laps=0)
        agent = rig.start()
        try:
            wait_for("the agent maps", lambda: rig.server_version() > 0, 120)
            seq = rig.post(rig.new_kernel_message())
            wait_for("the acknowledgement", lambda: rig.status_of(seq) != "queued", 120)
            message = rig.op.get(f"/robots/{rig.rid}/messages/{seq}").json()
        finally:
            code = agent.stop()
        assert code == 0, agent.output()[-3000:]
        counts = proxy.snapshot()
    assert message["status"] == "applied", message
    assert counts["kernel.cut"] == 1 and counts["kernel.drop"] == 1, counts
    assert counts["kernel.delivered"] >= 1


def run_netfault(live: Live, tmp_path: Path, uploads: int, seed: int) -> dict[str, Any]:
    t0 = time.monotonic()
    with _proxy(live, seed=seed, fault_rate=FAULT_RATE, max_s=3600) as proxy:
        rig = Rig(live, tmp_path / "robot.db", proxy.url, rate=RATE_HZ, laps=0)
        agent = rig.start()
        try:
            for j in range(1, MESSAGES + 1):
                goal = uploads * j // MESSAGES
                wait_for(
                    f"{goal} uploads through the proxy",
                    lambda: proxy.snapshot().get("upload.received", 0) >= goal,  # noqa: B023 (called here)
                    max(120.0, uploads * 0.2),
                )
                if j in KERNEL_AT:
                    rig.post(rig.new_kernel_message())
                else:
                    rig.post(f"<n-smax>{2 + j}</n-smax>")
            during = proxy.snapshot()
            proxy.fault_rate = 0.0
            wait_for(
                "every message dealt with",
                lambda: all(m["status"] != "queued" for m in server_messages(rig.op, rig.rid)),
                180,
            )
            mapped = int(robot_db_meta(rig.db, "map_version") or 0)
            wait_for("the server caught up", lambda: rig.server_version() >= mapped, 180)
        finally:
            code = agent.stop()
        assert code == 0, agent.output()[-3000:]
    view = read_robot_db(rig.db)
    check_final(live, rig.op, rig.rid, view)
    assert view is not None
    out = agent.output()
    assert "Traceback" not in out, out[out.index("Traceback") - 2000 :][:6000]
    faults = sum(v for k, v in during.items() if k.startswith("faults."))
    requests = sum(v for k, v in during.items() if k.endswith(".received"))
    assert during["upload.received"] >= uploads
    assert faults >= 0.2 * requests, f"{faults} faults in {requests} requests: the proxy injected too few"
    return {
        "uploads_target": uploads,
        "fault_rate": FAULT_RATE,
        "seed": seed,
        "agent_rate_hz": float(RATE_HZ),
        "map_versions": view.map_version,
        "server_accepted_uploads": len(upload_records(live, rig.rid)),
        "messages": len(server_messages(rig.op, rig.rid)),
        "messages_rolled_back_by_the_kernel_guard": sum(
            m["status"] == "rolled-back" for m in server_messages(rig.op, rig.rid)
        ),
        "proxy_during_faults": during,
        "proxy_total": proxy.snapshot(),
        "requests": requests,
        "faults": faults,
        "seconds": round(time.monotonic() - t0, 1),
    }


def test_every_version_once_and_messages_once_through_30_percent_faults(live: Live, tmp_path: Path) -> None:
    figures = run_netfault(live, tmp_path, UPLOADS, SEED)
    write_figures("netfault-fast", figures)


@pytest.mark.soak
def test_netfault_soak(live: Live, tmp_path: Path) -> None:
    figures = run_netfault(live, tmp_path, SOAK_UPLOADS, SEED + 1)
    write_figures("netfault-soak", figures)
