"""Kernel supply-chain helpers for the reliability suite (docs/reliability.md): artifacts with a built-in
behaviour or a planted fault, and white-box tampering with what the server stores.

Uploading, sending messages and reading kernel states reuse tests/robot_agent/test_agent_kernels_live.py's
helpers (imported here so the suite's tests have one place to import from); the agent is started here, to
drive the simulator until stopped.
"""

from __future__ import annotations

from pathlib import Path

import httpx
from sqlalchemy import select

from server.models import KernelArtifact
from shared.signing import KeyPair, generate_keypair, sha256_hex
from tests.robot_agent.agentproc import AgentProcess, wait_for
from tests.robot_agent.test_agent_kernels_live import XML, _noise, _send, _state, _upload
from tests.server.live import Live

__all__ = [
    "FAULTS",
    "XML",
    "agent",
    "dbscan",
    "noise",
    "send",
    "start",
    "state",
    "tamper",
    "trusted_key",
    "upload",
    "workers_of",
]

upload, send, state, noise = _upload, _send, _state, _noise


def agent(live: Live, db: Path, rid: int, token: str, key: KeyPair) -> AgentProcess:
    """``linemap agent`` for robot ``rid`` on the simulator, driving until stopped (``--laps 0``: a matrix
    of cases takes minutes, longer than one drive), trusting ``key``."""
    return AgentProcess(
        db,
        server=live.base_url,
        robot_id=rid,
        token=token,
        extra=["--rate", "20", "--laps", "0", "--trust-key", key.public_b64],
    )


def start(live: Live, folder: Path, key: KeyPair) -> tuple[AgentProcess, int, str, httpx.Client]:
    """A new robot and its agent (Robot DB ``folder/robot.db``), once it has uploaded its first map:
    ``(agent, robot id, robot token, operator client)``."""
    rid, token = live.new_robot()
    op = live.operator()
    proc = agent(live, folder / "robot.db", rid, token, key)
    wait_for("first map", lambda: op.get(f"/robots/{rid}").json()["map_version"] > 0, 120)
    return proc, rid, token, op


#: ``apply`` bodies planting one fault each (the built-in DBSCAN otherwise). ``{after}`` is how many calls
#: behave before the fault: 0 means from the first call, so the dry run meets it; a number above what the
#: dry run and the conformance battery make (about 20 calls) means the fault shows only in service.
FAULTS = {
    "hangs": "        while True:\n            pass",
    "allocates": (
        "        blocks = []\n"
        "        while True:\n"
        "            blocks.append(np.ones(1 << 20))  # 8 MB, written: real memory"
    ),
    "nan": (
        "        out = super().apply(points)\n"
        "        bad = np.full_like(np.asarray(out.points, dtype=float), np.nan)\n"
        "        return NoiseResult(out.keep, bad, out.labels)"
    ),
    "wrong-shapes": (
        "        return NoiseResult(np.ones(3, dtype=bool), np.zeros((2, 3)), np.zeros(7, dtype=np.intp))"
    ),
    "wrong-type": "        return [[0.0, 0.0]]",
    # A C call that holds the GIL for ever (catastrophic backtracking): only another process can stop it.
    "regex": (
        "        import re\n        re.match(r'(a+)+$', 'a' * 40 + 'b')\n        return super().apply(points)"
    ),
    # Loops only on an empty input: the dry run on real scans passes, the conformance battery hangs.
    "empty-loop": (
        "        if len(points) == 0:\n"
        "            while True:\n"
        "                pass\n"
        "        return super().apply(points)"
    ),
    "socket": (
        "        import socket\n"
        "        socket.create_connection(('127.0.0.1', 9), timeout=1).close()\n"
        "        return super().apply(points)"
    ),
    "read-file": "        open('/etc/hostname').read()\n        return super().apply(points)",
    "write-file": (
        "        import os\n"
        "        open(os.path.expanduser('~') + '/../linemap-kernel-was-here', 'w').write('x')\n"
        "        return super().apply(points)"
    ),
    "slow": (
        "        total = 0\n"
        "        for i in range(20_000_000):  # over the 200 ms per-call budget, under the 5 s hang limit\n"
        "            total += i\n"
        "        return super().apply(points)"
    ),
}


def dbscan(version: str, fault: str | None = None, after: int = 0) -> bytes:
    """A noise-removal module declaring DBSCAN ``version``: the built-in algorithm, or with ``fault``
    (a key of :data:`FAULTS`) from call ``after + 1`` on."""
    cls = "Dbscan" + version.replace(".", "_")
    head = (
        f'"""DBSCAN {version} (reliability test artifact{", fault " + fault if fault else ""})."""\n'
        "import numpy as np\n\n"
        "from shared.kernels import NoiseResult\n"
        "from shared.kernels.noise.dbscan import Dbscan\n\n"
        "_calls = [0]\n\n\n"
        f"class {cls}(Dbscan):\n"
        f'    """DBSCAN, version {version}."""\n\n'
        f'    version = "{version}"\n'
    )
    if fault == "import-hang":  # at import time, before any class exists
        return (head.replace("_calls = [0]", "while True:\n    pass\n_calls = [0]")).encode()
    if fault is None:
        return head.encode()
    body = (
        "\n    def apply(self, points):\n"
        "        _calls[0] += 1\n"
        f"        if _calls[0] <= {after}:\n"
        "            return super().apply(points)\n"
        f"{FAULTS[fault]}\n"
    )
    return (head + body).encode()


def workers_of(agent_pid: int) -> list[int]:
    """PIDs of the live kernel worker processes the agent ``agent_pid`` started (read from /proc: the
    worker's command line ends with its agent's PID), whether the agent is still alive or not."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            raw = (entry / "cmdline").read_bytes().split(b"\0")
            state = (entry / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        argv = [a.decode(errors="replace") for a in raw if a]
        if "robot_agent.kernels.worker" in argv and argv[-1] == str(agent_pid) and state != "Z":
            found.append(int(entry.name))
    return found


def tamper(live: Live, name: str, version: str, source: bytes, *, fix_digest: bool = False) -> str:
    """Replace the bytes the server stores for kernel ``name`` ``version`` (as an attacker with write
    access to the server's storage would); with ``fix_digest`` the stored sha256 too (the signature then
    no longer covers it). Returns the sha256 the server now announces."""
    with live.state.db.session() as s:
        art = s.scalars(
            select(KernelArtifact).where(KernelArtifact.name == name, KernelArtifact.version == version)
        ).one()
        art.source = source
        art.size_bytes = len(source)
        if fix_digest:
            art.sha256 = sha256_hex(source)
        return art.sha256


def trusted_key(live: Live) -> KeyPair:
    """A new signing key pair whose public half the server ``live`` trusts (registered as 'ops')."""
    pair = generate_keypair()
    with live.operator() as op:
        assert op.post("/keys", json={"name": "ops", "public_key": pair.public_b64}).status_code == 201
    return pair
