"""Rollout timeline: one ``linemap server`` process (fresh SQLite file) and ``--robots`` robots simulated
over HTTP (each long-polls its messages, acknowledges them and reports its status with map uploads, as the
agent does). Two rollouts of a signed noise-removal kernel:

1. healthy: every robot applies the update and reports it active; printed: each robot's wave and when it
   was sent, applied and committed, in seconds after the rollout started;
2. failing canary: the canary's step time triples under the new version; printed: the stop reason, each
   robot's state, and how many messages the other robots received (0 expected).

Figures, not pass/fail (the behaviour is asserted in tests/server/test_rollouts_api.py). Exit 0 when it
ran, 2 when the setup failed. ``--help`` for the options."""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import threading
import time
import uuid
from datetime import datetime
from pathlib import Path
from typing import Any

import httpx

if __package__ in (None, ""):  # run as a script: benchmarks/ is not a package on sys.path then
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.server_load import Server, SetupError
from shared.control import OperationKind, parse_message
from shared.signing import generate_keypair, load_private_key, sha256_hex, sign_digest

__all__ = ["main"]

OLD = "dbscan@1.0.0"


class Robot(threading.Thread):
    """A simulated robot: long-polls, acknowledges ``applied``, reports ``step_ms`` (x ``slow`` under the
    new version)."""

    def __init__(self, base: str, rid: int, token: str, slow: float = 1.0) -> None:
        super().__init__(daemon=True)
        self.rid, self.slow = rid, slow
        self.http = httpx.Client(base_url=base, headers={"Authorization": f"Bearer {token}"}, timeout=30)
        self.after, self.version, self.received = 0, 0, 0
        self.stop = threading.Event()
        self.report(OLD, 10.0)

    def report(self, active: str, step_ms: float) -> None:
        self.version += 1
        status = {"active_kernels": {"noise-removal": active}, "step_ms": step_ms}
        self.http.post(f"/robots/{self.rid}/maps", json={"version": self.version, "status": status})

    def run(self) -> None:
        while not self.stop.is_set():
            got = self.http.get(
                f"/robots/{self.rid}/messages", params={"after": self.after, "wait": 1}
            ).json()
            for m in got["messages"]:
                self.after = m["seq"]
                self.received += 1
                op = parse_message(m["xml"]).operations[0]
                self.http.post(f"/robots/{self.rid}/messages/{m['seq']}/ack", json={"outcome": "applied"})
                new = op.kind is OperationKind.UPDATE
                self.report(f"{op.name}@{op.version}", 10.0 * (self.slow if new else 1.0))


def _t(at: str | None, t0: datetime) -> str:
    return "-" if at is None else f"{(datetime.fromisoformat(at) - t0).total_seconds():6.2f}"


def _run(op: httpx.Client, base: str, n: int, body: dict[str, Any], slow_canary: bool) -> dict[str, Any]:
    robots = []
    for i in range(n):
        r = op.post("/robots", json={"name": f"sim-{uuid.uuid4().hex[:8]}"}).json()
        robots.append(Robot(base, r["id"], r["token"], slow=3.0 if slow_canary and i == 0 else 1.0))
    for robot in robots:
        robot.start()
    started = op.post("/rollouts", json={**body, "robots": [r.rid for r in robots]}).json()
    while True:
        got = op.get(f"/rollouts/{started['id']}").json()
        if got["state"] in ("completed", "stopped") and not got["active"]:
            break
        time.sleep(0.05)
    time.sleep(1.5)  # let the robots take the last messages (rollbacks) before counting
    for robot in robots:
        robot.stop.set()
    got["received"] = {r.rid: r.received for r in robots}
    return dict(got)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robots", type=int, default=10)
    ap.add_argument("--canaries", type=int, default=1)
    ap.add_argument("--wave-size", type=int, default=3)
    ap.add_argument("--window-s", type=float, default=2.0, help="commit window (s)")
    args = ap.parse_args(argv)
    os.environ.setdefault("LINEMAP_ROLLOUT_TICK_S", "0.2")
    with tempfile.TemporaryDirectory() as tmp:
        server = Server(f"sqlite:///{Path(tmp) / 'server.db'}", 0, Path(tmp))
        try:
            token = server.start()
            op = httpx.Client(base_url=server.base + "/api/v1", headers={"Authorization": f"Bearer {token}"})
            key = generate_keypair()
            op.post("/keys", json={"name": "bench", "public_key": key.public_b64})
            source = b'"""rollout benchmark kernel"""\n'
            sig = sign_digest(load_private_key(key.private_pem), sha256_hex(source))
            form = {"name": "dbscan", "stage": "noise-removal", "version": "1.1.0", "signature": sig}
            up = op.post("/kernels", data=form, files={"file": ("k.py", source, "text/x-python")})
            if up.status_code != 201:
                raise SetupError(f"kernel upload: {up.text}")
            body = {
                "stage": "noise-removal",
                "name": "dbscan",
                "version": "1.1.0",
                "sha256": sha256_hex(source),
                "canaries": args.canaries,
                "wave_size": args.wave_size,
                "commit_window_s": args.window_s,
                "max_failure_share": 0.2,
            }
            base = server.base + "/api/v1"
            for title, slow in (("healthy", False), ("failing canary (step time x3)", True)):
                got = _run(op, base, args.robots, body, slow)
                t0 = datetime.fromisoformat(got["created_at"])
                print(f"\n{title}: rollout {got['id']} {got['state']}; {got['counts']}")
                if got["stop_reason"]:
                    print(f"  stop reason: {got['stop_reason']}")
                print("  robot  wave  state         sent_s  applied_s  done_s  messages  reason")
                for r in got["robots"]:
                    print(
                        f"  {r['robot_id']:5d}  {r['wave']:4d}  {r['state']:12s}  {_t(r['sent_at'], t0)}  "
                        f"{_t(r['applied_at'], t0):>9s}  {_t(r['finished_at'], t0)}  "
                        f"{got['received'][r['robot_id']]:8d}  {r['reason'] or ''}"
                    )
        except SetupError as exc:
            print(f"setup failed: {exc}", file=sys.stderr)
            return 2
        finally:
            server.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
