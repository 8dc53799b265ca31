"""What a downloaded kernel can reach from its worker process (robot_agent/kernels/sandbox.py,
docs/reliability/sandbox.md): a real worker, confined as the agent confines it, runs a kernel that tries
each escape and reports what happened (through the only channel it has: the text of an exception).
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from robot_agent.kernels.dryrun import load_in_worker
from robot_agent.kernels.proc import KernelCallError

PROBES = b"""
import json, os, signal, socket
from shared.kernels.noise.dbscan import Dbscan


def _try(fn):
    try:
        fn()
        return "allowed"
    except Exception as exc:
        return type(exc).__name__


def _open_fds():
    found = []
    for fd in range(256):
        try:
            os.fstat(fd)
            found.append(fd)
        except OSError:
            pass
    return found


def _fill():
    for i in range(64):
        with open(f"fill{i}", "wb") as f:
            f.write(b"x" * (1 << 20))


class Probe(Dbscan):
    version = "8.0.0"

    def apply(self, points):
        target = os.environ.get("PROBE_TARGET", "")
        out = {
            "env": sorted(os.environ),
            "fds": _open_fds(),
            "socket": _try(lambda: socket.socket(socket.AF_INET, socket.SOCK_STREAM)),
            "unix-socket": _try(lambda: socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)),
            "read-etc": _try(lambda: open("/etc/hostname").read()),
            "read-proc-parent": _try(lambda: open(f"/proc/{os.getppid()}/environ").read()),
            "write-tmp": _try(lambda: open("/tmp/linemap-probe-was-here", "w").write("x")),
            "write-scratch": _try(lambda: open("note.txt", "w").write("x")),
            "fill-scratch": _try(_fill),
            "fork": _try(lambda: os.fork() or os._exit(0)),
            "signal-parent": _try(lambda: os.kill(os.getppid(), 0)),
        }
        raise RuntimeError("PROBE" + json.dumps(out))
"""


@pytest.fixture
def probe(monkeypatch: pytest.MonkeyPatch) -> Iterator[dict[str, Any]]:
    monkeypatch.setenv("LINEMAP_ROBOT_TOKEN", "secret-token-of-the-agent")
    cls: Any = load_in_worker(
        PROBES, "noise-removal", "dbscan", "8.0.0", memory_mb=256, call_s=30, import_s=30
    )
    try:
        with pytest.raises(KernelCallError) as exc:
            cls().apply(np.zeros((3, 2)))
        text = exc.value.reason
        assert "PROBE" in text, text
        found: dict[str, Any] = json.loads(text.split("PROBE", 1)[1].rsplit(" (line", 1)[0])
        found["confinement"] = cls.worker.confinement
        found["scratch_on_host"] = sorted(os.listdir(cls.worker.scratch))
        yield found
    finally:
        cls.worker.close()


def test_the_worker_has_no_inherited_credentials_or_descriptors(probe: dict[str, Any]) -> None:
    assert "LINEMAP_ROBOT_TOKEN" not in probe["env"]
    assert set(probe["env"]) <= {
        "HOME",
        "TMPDIR",
        "PYTHONPATH",
        "OPENBLAS_NUM_THREADS",
        "OMP_NUM_THREADS",
        "MKL_NUM_THREADS",
        "NUMBA_NUM_THREADS",
        "LC_CTYPE",
    }
    # stdin and stdout on /dev/null, stderr to a log in its scratch directory, the socket to the agent; and
    # whatever Python itself opened after that (nothing of the agent's: close_fds, only the socket passed)
    assert probe["fds"][:3] == [0, 1, 2] and len(probe["fds"]) <= 5, probe["fds"]


def test_no_network_and_no_file_outside_scratch(probe: dict[str, Any]) -> None:
    assert probe["confinement"]["landlock"].startswith("applied"), probe["confinement"]
    for what in ("socket", "unix-socket", "read-etc", "read-proc-parent", "write-tmp"):
        assert probe[what] in ("PermissionError", "OSError"), (what, probe[what])
    assert not Path("/tmp/linemap-probe-was-here").exists()
    assert probe["write-scratch"] == "allowed"


def test_scratch_is_private_and_bounded(probe: dict[str, Any]) -> None:
    assert probe["confinement"]["scratch"].startswith("applied"), probe["confinement"]
    assert probe["fill-scratch"] == "OSError"  # No space left on device, at 16 MB
    assert probe["scratch_on_host"] == ["stderr.log"]  # the kernel's files lived in its own tmpfs


def test_no_child_processes_and_no_signals_out(probe: dict[str, Any]) -> None:
    assert probe["confinement"]["seccomp"] == "applied", probe["confinement"]
    assert probe["fork"] == "PermissionError"
    assert probe["signal-parent"] == "PermissionError"
