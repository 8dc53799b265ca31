"""Kernel hot-swap through a real server and a real agent process: a signed kernel is uploaded, installed,
used and rolled back; a kernel that raises is rolled back automatically while mapping goes on; an artifact
signed by a key the robot does not trust is refused with the reason (docs/design.md §7, §9)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from shared.signing import KeyPair, generate_keypair, load_private_key, sha256_hex, sign_digest
from tests.robot_agent.agentproc import AgentProcess, send_message, wait_for
from tests.server.live import Live, start_live

GOOD = b'''"""DBSCAN 1.1.0: the built-in algorithm under a new version (test artifact)."""
from shared.kernels.noise.dbscan import Dbscan


class Dbscan110(Dbscan):
    """DBSCAN, version 1.1.0."""

    version = "1.1.0"
'''

# Passes the conformance battery and the dry run (each in a fresh process or well under 400 calls), then
# fails in service.
FLAKY = b'''"""DBSCAN 1.2.0 that breaks after a while in service (test artifact)."""
from shared.kernels.noise.dbscan import Dbscan

_calls = [0]


class Dbscan120(Dbscan):
    """DBSCAN, version 1.2.0, raises after 400 calls."""

    version = "1.2.0"

    def apply(self, points):
        _calls[0] += 1
        if _calls[0] > 400:
            raise RuntimeError("sensor buffer overflow (injected)")
        return super().apply(points)
'''

XML = {"Content-Type": "application/xml"}


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    yield from start_live("sqlite", tmp_path_factory.mktemp("kernel-server"), poll_recheck_s=1.0)


@pytest.fixture(scope="module")
def key() -> KeyPair:
    return generate_keypair()


def _upload(op: httpx.Client, key: KeyPair, source: bytes, version: str, name: str = "dbscan") -> str:
    digest = sha256_hex(source)
    sig = sign_digest(load_private_key(key.private_pem), digest)
    r = op.post(
        "/kernels",
        data={"name": name, "stage": "noise-removal", "version": version, "signature": sig},
        files={"file": (f"{name}.py", source, "text/x-python")},
    )
    assert r.status_code in (200, 201), r.text
    return digest


def _send(op: httpx.Client, rid: int, body: str) -> dict[str, Any]:
    return send_message(op, rid, body)


def _noise(op: httpx.Client, rid: int) -> str:
    return str(op.get(f"/robots/{rid}").json()["active_kernels"].get("noise-removal"))


def _state(op: httpx.Client, rid: int, version: str) -> str | None:
    kernels = op.get(f"/robots/{rid}").json()["kernels"] or []
    return next((k["state"] for k in kernels if k["name"] == "dbscan" and k["version"] == version), None)


def _start(live: Live, tmp_path: Path, key: KeyPair) -> tuple[AgentProcess, int, httpx.Client]:
    rid, token = live.new_robot()
    op = live.operator()
    agent = AgentProcess(
        tmp_path / "robot.db",
        server=live.base_url,
        robot_id=rid,
        token=token,
        extra=["--rate", "20", "--laps", "0", "--trust-key", key.public_b64],  # patrol until stopped
    )
    wait_for("first map", lambda: op.get(f"/robots/{rid}").json()["map_version"] > 0)
    return agent, rid, op


def test_install_use_and_roll_back_a_signed_kernel(live: Live, tmp_path: Path, key: KeyPair) -> None:
    with live.operator() as op:
        assert op.post("/keys", json={"name": "ops", "public_key": key.public_b64}).status_code in (201, 409)
        digest = _upload(op, key, GOOD, "1.1.0")
    agent, rid, op = _start(live, tmp_path, key)
    try:
        ack = _send(
            op, rid, f'<kernel-update stage="noise-removal" name="dbscan" version="1.1.0" sha256="{digest}"/>'
        )
        assert ack["status"] == "applied", ack
        wait_for("dbscan 1.1.0 in use", lambda: _noise(op, rid) == "dbscan@1.1.0")
        wait_for("1.1.0 reported active", lambda: _state(op, rid, "1.1.0") == "active")
        used_from = op.get(f"/robots/{rid}").json()["map_version"]
        wait_for("steps with 1.1.0", lambda: op.get(f"/robots/{rid}").json()["map_version"] > used_from + 10)
        back = _send(
            op,
            rid,
            '<kernel-rollback stage="noise-removal" name="dbscan" version="1.0.0" below-floor="allow"/>',
        )
        assert back["status"] == "applied", back
        wait_for("dbscan 1.0.0 back in use", lambda: _noise(op, rid) == "dbscan@1.0.0")
        # The robot reports its kernel store: 1.1.0 stays there, ready, but no longer runs.
        wait_for("1.1.0 kept, not active", lambda: _state(op, rid, "1.1.0") == "verified")
    finally:
        assert agent.stop() == 0, agent.output()


EXAMPLE = Path(__file__).parents[2] / "docs" / "examples" / "radius_outlier.py"


def test_a_kernel_of_a_new_name_is_installed_chosen_and_runs(
    live: Live, tmp_path: Path, key: KeyPair
) -> None:
    """The README's "Writing your own" path: the example radius-outlier filter, signed and uploaded, is
    installed, put into the noise-removal chain by name with its own parameters, and runs; its parameters
    are checked against its own model on the robot (the server has no model of uploaded code)."""
    with live.operator() as op:
        assert op.post("/keys", json={"name": "ops", "public_key": key.public_b64}).status_code in (201, 409)
        digest = _upload(op, key, EXAMPLE.read_bytes(), "1.0.0", name="radius-outlier")
    agent, rid, op = _start(live, tmp_path, key)
    try:
        unknown = op.post(
            f"/robots/{rid}/messages",
            content='<xml><message><noise-removal><kernel name="median-filter"/></noise-removal>'
            "</message></xml>",
            headers=XML,
        )
        assert unknown.status_code == 422, unknown.text
        assert "median-filter" in unknown.json()["detail"] and "dbscan" in unknown.json()["detail"]
        install = (
            '<kernel-install stage="noise-removal" name="radius-outlier" version="1.0.0" '
            f'sha256="{digest}"/>'
        )
        # uploaded without a declared parameter schema: the robot alone checks the parameters, against
        # the code, and refuses the whole message (install included), keeping the settings it had
        too_wide = _send(
            op,
            rid,
            install + '<noise-removal><kernel name="radius-outlier"><param name="radius_m" unit="m">9</param>'
            "</kernel></noise-removal>",
        )
        assert too_wide["status"] == "rejected", too_wide
        assert "radius_m" in too_wide["reason"] and "5" in too_wide["reason"], too_wide["reason"]
        assert _noise(op, rid) == "dbscan@1.0.0"
        # one message installs the kernel and puts it into the chain
        chosen = _send(
            op,
            rid,
            install + '<noise-removal><kernel name="radius-outlier">'
            '<param name="radius_m" unit="cm">6</param><param name="min_neighbours">2</param>'
            "</kernel></noise-removal>",
        )
        assert chosen["status"] == "applied", chosen
        wait_for("radius-outlier in use", lambda: _noise(op, rid) == "radius-outlier@1.0.0")
        robot = op.get(f"/robots/{rid}").json()
        assert robot["config"]["noise_removal"][0]["params"]["radius_m"] == pytest.approx(0.06)
        used_from = robot["map_version"]
        wait_for(
            "steps with radius-outlier",
            lambda: op.get(f"/robots/{rid}").json()["map_version"] > used_from + 10,
        )
        walls = op.get(f"/robots/{rid}/maps/latest").json()["segments"]
        assert len(walls) > 0
    finally:
        assert agent.stop() == 0, agent.output()


def test_a_kernel_that_raises_is_rolled_back_while_mapping_goes_on(
    live: Live, tmp_path: Path, key: KeyPair
) -> None:
    with live.operator() as op:
        assert op.post("/keys", json={"name": "ops", "public_key": key.public_b64}).status_code in (201, 409)
        digest = _upload(op, key, FLAKY, "1.2.0")
    agent, rid, op = _start(live, tmp_path, key)
    try:
        ack = _send(
            op, rid, f'<kernel-update stage="noise-removal" name="dbscan" version="1.2.0" sha256="{digest}"/>'
        )
        assert ack["status"] == "applied", ack
        seq = op.get(f"/robots/{rid}").json()["last_seq"]
        rolled = wait_for(
            "automatic rollback",
            lambda: (m := op.get(f"/robots/{rid}/messages/{seq}").json())["status"] == "rolled-back" and m,
            120,
        )
        assert "RuntimeError" in rolled["reason"] and "sensor buffer overflow" in rolled["reason"]
        wait_for("dbscan 1.0.0 in use again", lambda: _noise(op, rid) == "dbscan@1.0.0")
        robot = op.get(f"/robots/{rid}").json()
        assert "rolled back" in (robot["last_error"] or "")
        after = robot["map_version"]
        wait_for("mapping goes on", lambda: op.get(f"/robots/{rid}").json()["map_version"] > after + 10)
    finally:
        assert agent.stop() == 0, agent.output()


def test_kernel_signed_by_an_untrusted_key_is_refused(live: Live, tmp_path: Path, key: KeyPair) -> None:
    stranger = generate_keypair()  # the server accepts it, the robot does not trust it
    with live.operator() as op:
        assert (
            op.post("/keys", json={"name": "stranger", "public_key": stranger.public_b64}).status_code == 201
        )
        digest = _upload(
            op, stranger, GOOD.replace(b"1.1.0", b"1.3.0").replace(b"Dbscan110", b"Dbscan130"), "1.3.0"
        )
    agent, rid, op = _start(live, tmp_path, key)
    try:
        ack = _send(
            op,
            rid,
            f'<kernel-install stage="noise-removal" name="dbscan" version="1.3.0" sha256="{digest}"/>',
        )
        assert ack["status"] == "rejected"
        assert "signature" in ack["reason"] and "1.3.0" in ack["reason"], ack["reason"]
        assert _noise(op, rid) == "dbscan@1.0.0"
    finally:
        assert agent.stop() == 0, agent.output()


def test_wrong_sha256_and_unsigned_uploads_never_reach_a_robot(live: Live, key: KeyPair) -> None:
    """The server refuses both before a robot sees them (the robot's own checks of the same are in
    test_kernel_checks.py)."""
    rid, _ = live.new_robot()
    with live.operator() as op:
        assert op.post("/keys", json={"name": "ops", "public_key": key.public_b64}).status_code in (201, 409)
        _upload(op, key, GOOD, "1.1.0")
        r = op.post(
            f"/robots/{rid}/messages",
            content=f'<xml><message><kernel-update stage="noise-removal" name="dbscan" version="1.1.0" '
            f'sha256="{"0" * 64}"/></message></xml>',
            headers=XML,
        )
        assert r.status_code == 422 and "does not match" in r.json()["detail"]
        unsigned = op.post(
            "/kernels",
            data={"name": "dbscan", "stage": "noise-removal", "version": "1.4.0", "signature": ""},
            files={"file": ("dbscan.py", GOOD, "text/x-python")},
        )
        assert unsigned.status_code == 422 and "signature" in unsigned.json()["detail"]


LATE = FLAKY.replace(b"1.2.0", b"1.4.0").replace(b"Dbscan120", b"Dbscan140").replace(b"> 400", b"> 200")


def test_a_rollback_keeps_the_settings_of_later_messages(live: Live, tmp_path: Path, key: KeyPair) -> None:
    """A kernel that fails after other messages were applied is taken out alone: the robot runs the
    version it replaced with the later settings kept, and later messages still apply (found by the
    network-fault soak: the rollback put back the configuration before the *last* message, which still
    selected the failed kernel, so every later message was rejected with "has no version")."""
    with live.operator() as op:
        assert op.post("/keys", json={"name": "ops", "public_key": key.public_b64}).status_code in (201, 409)
        digest = _upload(op, key, LATE, "1.4.0")
    agent, rid, op = _start(live, tmp_path, key)
    try:
        update = f'<kernel-update stage="noise-removal" name="dbscan" version="1.4.0" sha256="{digest}"/>'
        assert _send(op, rid, update)["status"] == "applied"
        seq = op.get(f"/robots/{rid}").json()["last_seq"]
        assert _send(op, rid, "<n-smax>7</n-smax>")["status"] == "applied"  # after the kernel's message
        wait_for(
            "automatic rollback",
            lambda: op.get(f"/robots/{rid}/messages/{seq}").json()["status"] == "rolled-back",
            120,
        )
        wait_for("dbscan 1.0.0 in use again", lambda: _noise(op, rid) == "dbscan@1.0.0")
        assert op.get(f"/robots/{rid}").json()["config"]["n_smax"] == 7, "the later setting was lost"
        later = _send(op, rid, "<n-smax>9</n-smax>")
        assert later["status"] == "applied", later
    finally:
        assert agent.stop() == 0, agent.output()
