"""Robots simulated over HTTP for the rollout tests: each polls its messages, acknowledges them and reports
its status with map uploads, as the agent does; and a signed kernel uploaded to roll out."""

from __future__ import annotations

import itertools
import uuid
from collections.abc import Callable

from shared.control import OperationKind, parse_message
from shared.signing import KeyPair, load_private_key, sha256_hex, sign_digest
from tests.server.live import Live

#: The noise-removal kernel every simulated robot runs before a rollout.
OLD = "dbscan@1.0.0"


_MINORS = itertools.count(1)


def upload_kernel(live: Live, key: KeyPair) -> dict[str, str]:
    """A signed new version of ``dbscan`` (the kernel the simulated robots run) on the server, a version
    number of its own each call (1.1.0, 1.2.0, ...): ``{stage, name, version, sha256}``."""
    version = f"1.{next(_MINORS)}.0"
    with live.operator() as op:
        r = op.post("/keys", json={"name": "ci", "public_key": key.public_b64})
        assert r.status_code in (201, 409), r.text
        source = f'"""rollout test kernel {uuid.uuid4().hex}"""\n'.encode()
        name = "dbscan"
        sig = sign_digest(load_private_key(key.private_pem), sha256_hex(source))
        data = {"name": name, "stage": "noise-removal", "version": version, "signature": sig}
        r = op.post("/kernels", data=data, files={"file": (f"{name}.py", source, "text/x-python")})
        assert r.status_code == 201, r.text
    return {"stage": "noise-removal", "name": name, "version": version, "sha256": sha256_hex(source)}


class SimRobot:
    """A robot over HTTP: polls its messages, acknowledges them, reports its status with map uploads."""

    def __init__(self, live: Live) -> None:
        self.id, token = live.new_robot()
        self.http = live.client(token)
        self.after = 0
        self.version = 0
        self.got: list[tuple[int, str]] = []  # (seq, xml) of every message received
        self.report(active=OLD, step_ms=10.0)

    def report(self, *, active: str, step_ms: float = 10.0, last_error: str | None = None) -> None:
        self.version += 1
        status = {"active_kernels": {"noise-removal": active}, "step_ms": step_ms, "last_error": last_error}
        up = {"version": self.version, "base_version": None, "status": status}
        r = self.http.post(f"/robots/{self.id}/maps", json=up)
        assert r.status_code == 200, r.text

    def poll(self) -> list[tuple[int, str]]:
        r = self.http.get(f"/robots/{self.id}/messages", params={"after": self.after})
        assert r.status_code == 200, r.text
        new = [(m["seq"], m["xml"]) for m in r.json()["messages"]]
        if new:
            self.after = new[-1][0]
        self.got += new
        return new

    def ack(self, seq: int, outcome: str, reason: str | None = None) -> None:
        r = self.http.post(
            f"/robots/{self.id}/messages/{seq}/ack", json={"outcome": outcome, "reason": reason}
        )
        assert r.status_code == 200, r.text

    def serve(self, on_update: Callable[[SimRobot, int, str], None]) -> None:
        """Handle the messages queued since the last call: ``on_update(robot, seq, xml)`` for an update, and
        a rollback is applied (reported active again)."""
        for seq, xml in self.poll():
            op = parse_message(xml).operations[0]
            if op.kind is OperationKind.UPDATE:
                on_update(self, seq, xml)
            elif op.kind is OperationKind.ROLLBACK:
                self.ack(seq, "applied")
                self.report(active=f"{op.name}@{op.version}")


def healthy(robot: SimRobot, seq: int, xml: str) -> None:
    op = parse_message(xml).operations[0]
    robot.ack(seq, "applied")
    robot.report(active=f"{op.name}@{op.version}")
