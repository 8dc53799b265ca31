"""A running ``linemap demo`` and Debian's Chromium driven by Playwright, for the dashboard's browser tests.

Chromium is the system's (``/usr/bin/chromium``, Debian package ``chromium``; ``LINEMAP_CHROMIUM`` overrides);
a browser is never downloaded. Screenshots and measured figures go to ``test-artifacts/dashboard/`` (or
``$LINEMAP_TEST_ARTIFACTS``), which CI keeps.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import httpx

from tests.robot_agent.agentproc import wait_for

ROOT = Path(__file__).resolve().parents[3]
CHROMIUM = os.environ.get("LINEMAP_CHROMIUM", "/usr/bin/chromium")
ARTIFACTS = Path(os.environ.get("LINEMAP_TEST_ARTIFACTS", ROOT / "test-artifacts")) / "dashboard"
LINEMAP = str(Path(sys.executable).parent / "linemap")
#: Headless, and no calls to Google's services (this machine's network is closed).
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextmanager
def running_demo(directory: Path) -> Iterator[dict[str, Any]]:
    """``linemap demo`` on a free port; yields its ``demo.json``; Ctrl-C at the end (must exit 0)."""
    port = free_port()
    directory.mkdir(parents=True, exist_ok=True)
    out = (directory / "demo.out").open("wb")
    proc = subprocess.Popen(
        [LINEMAP, "demo", "--dir", str(directory), "--port", str(port)], stdout=out, stderr=subprocess.STDOUT
    )
    try:
        info_file = directory / "demo.json"
        wait_for("linemap demo to start", lambda: info_file.is_file() or proc.poll() is not None, 120)
        assert proc.poll() is None, (directory / "demo.out").read_text()
        info = json.loads(info_file.read_text())
        with operator_client(info) as op:
            wait_for(
                "the robot's first map",
                lambda: op.get(f"/robots/{info['robot_id']}").json()["map_version"] > 0,
            )
        yield info
        proc.send_signal(signal.SIGINT)
        assert proc.wait(90) == 0, (directory / "demo.out").read_text()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        out.close()


def operator_client(info: dict[str, Any]) -> httpx.Client:
    return httpx.Client(
        base_url=info["url"] + "api/v1",
        headers={"Authorization": f"Bearer {info['operator_token']}"},
        timeout=30,
    )


def launch_chromium(playwright: Any) -> Any:
    if not Path(CHROMIUM).is_file():
        raise RuntimeError(
            f"no Chromium at {CHROMIUM}: install Debian's package (apt-get install chromium) "
            "or set LINEMAP_CHROMIUM"
        )
    return playwright.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)


def logged_in_page(browser: Any, base_url: str, token: str) -> tuple[Any, list[str]]:
    """A new page (1280 x 800, 30 s timeouts) logged in with ``token`` at ``base_url``, and the list its
    uncaught errors go to."""
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    page.set_default_timeout(30_000)
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    page.goto(base_url + "/")
    page.get_by_test_id("login-token").fill(token)
    page.get_by_test_id("login-submit").click()
    return page, errors


def save_figures(name: str, figures: dict[str, Any]) -> Path:
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    path = ARTIFACTS / f"{name}.json"
    path.write_text(json.dumps(figures, indent=2) + "\n")
    return path
