"""Make the README's dashboard screenshots again: ``linemap demo`` (a real server and a simulated robot
agent on loopback), two more robots over HTTP that take part in a kernel rollout, and Debian's Chromium
through Playwright (never a downloaded browser).

    .venv/bin/python docs/screenshots.py [--out docs/images] [--versions 40]

Writes ``fleet.png``, ``rollouts.png``, ``map-tools.png`` (layers with the occupancy grid, a measured
angle, the download menu) and ``history.png`` (the history slider on a past version), each reduced to a
256-colour palette so that it stays small (< 200 KB). Prints each file's size.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from PIL import Image

from shared.signing import generate_keypair
from tests.robot_agent.agentproc import wait_for
from tests.server.dashboard.browser import launch_chromium, operator_client, running_demo
from tests.server.live import Live
from tests.server.rolloutsim import SimRobot, healthy, upload_kernel

VIEWPORT = {"width": 1280, "height": 760}


def _save(page: Any, out: Path, name: str) -> None:
    raw = out / f"{name}.raw.png"
    page.screenshot(path=str(raw))
    with Image.open(raw) as img:
        img.convert("RGB").quantize(colors=256, method=Image.Quantize.MEDIANCUT).save(
            out / f"{name}.png", optimize=True
        )
    raw.unlink()
    print(f"{out / name}.png: {(out / f'{name}.png').stat().st_size / 1024:.0f} KB")


def _shim(info: dict[str, Any]) -> Live:
    """The demo's server as the test helpers' Live (URL and operator token; no in-process state)."""
    return Live(info["url"].rstrip("/"), info["operator_token"], None, "sqlite", None)  # type: ignore[arg-type]


def _copy_map(robot: SimRobot, walls: list[list[float]], dx: float) -> None:
    """Give a simulated robot the demo robot's walls, shifted by ``dx`` m, as a new snapshot."""
    robot.version += 1
    body = {
        "version": robot.version,
        "base_version": None,
        "segments": [[w[0], w[1] + dx, w[2], w[3] + dx, w[4]] for w in walls],
        "pose": [1.0 + dx, 1.0, 0.8],
        "trajectory": [[float(i), 0.5 + dx + 0.05 * i, 1.0, 0.0] for i in range(40)],
    }
    r = robot.http.post(f"/robots/{robot.id}/maps", json=body)
    assert r.status_code == 200, r.text


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "images")
    ap.add_argument("--versions", type=int, default=40, help="map versions the demo robot uploads first")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    from playwright.sync_api import expect, sync_playwright

    with tempfile.TemporaryDirectory() as tmp, running_demo(Path(tmp) / "demo") as info:
        rid = info["robot_id"]
        with operator_client(info) as op:
            wait_for(
                f"{args.versions} map versions",
                lambda: op.get(f"/robots/{rid}").json()["map_version"] >= args.versions,
                300,
            )
            walls = op.get(f"/robots/{rid}/maps/latest").json()["segments"]
        live = _shim(info)
        helpers = [SimRobot(live), SimRobot(live)]
        for i, robot in enumerate(helpers, start=1):
            _copy_map(robot, walls, 12.0 * i)
        kernel = upload_kernel(live, generate_keypair())
        with sync_playwright() as p:
            browser = launch_chromium(p)
            page = browser.new_context(viewport=VIEWPORT).new_page()
            page.set_default_timeout(60_000)
            page.goto(info["url"])
            page.get_by_test_id("login-token").fill(info["operator_token"])
            page.get_by_test_id("login-submit").click()
            page.get_by_test_id("login-token").wait_for(state="detached")

            page.goto(info["url"] + "#/fleet")
            expect(page.get_by_test_id("fleet-card")).to_have_count(3)
            page.wait_for_timeout(2500)  # the cards' thumbnails (fetched once each)
            _save(page, args.out, "fleet")

            page.goto(info["url"] + "#/rollouts")
            page.get_by_test_id("rollout-kernel").select_option(
                label=f"{kernel['name']}@{kernel['version']} (noise-removal)"
            )
            page.get_by_test_id(f"rollout-robot-{rid}").uncheck()  # the demo's own agent keeps its kernel
            page.get_by_test_id("rollout-wave-size").fill("1")
            page.get_by_test_id("rollout-window").fill("0.5")
            page.get_by_test_id("rollout-start").click()
            expect(page.get_by_test_id("rollout-state")).to_have_attribute("data-status", "running")
            deadline = time.monotonic() + 60
            while page.locator('[data-testid="rollout-robot-row"][data-state="installed"]').count() < 1:
                assert time.monotonic() < deadline, "the canary did not commit"
                for robot in helpers:
                    robot.serve(healthy)
                page.wait_for_timeout(100)
            _save(page, args.out, "rollouts")

            page.goto(f"{info['url']}#/robots/{rid}")
            page.get_by_test_id("map-layer-occupancy").check()
            page.wait_for_function("() => window.linemapStats.occupancy_version !== null")
            page.get_by_test_id("map-measure").click()
            canvas = page.get_by_test_id("map-canvas").bounding_box()
            cx, cy = canvas["x"] + canvas["width"] / 2, canvas["y"] + canvas["height"] / 2
            for dx, dy in [(-160, 90), (0, 0), (150, 80)]:  # three points: an angle
                page.mouse.click(cx + dx, cy + dy)
            page.get_by_test_id("map-download").click()
            _save(page, args.out, "map-tools")

            page.keyboard.press("Escape")
            page.get_by_test_id("map-download").click()  # closes the menu
            page.get_by_test_id("map-layer-occupancy").uncheck()
            page.get_by_test_id("history-range").fill("8")
            expect(page.get_by_test_id("history-label")).to_contain_text(" of ")
            page.wait_for_timeout(500)
            _save(page, args.out, "history")
            browser.close()
        for robot in helpers:
            robot.http.close()


if __name__ == "__main__":
    main()
