"""Loop-closure corrections in a real browser (Debian's Chromium via Playwright): a real agent process with
loop closure maps two laps round a block (``sim:loop-block``) into a real server on 127.0.0.1 while the
robot's live map is open. The page follows the corrections delta by delta, without a reload or a new
snapshot: its walls, keyframes, loop closures and its trajectory (moved in place by the corrected keyframes)
end up equal to what the server holds; the "keyframes" and "loop closures" layers switch; the pose readout
shows the 1-sigma uncertainty the robot sent."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.robot_agent.agentproc import AgentProcess, wait_for
from tests.server.dashboard.browser import ARTIFACTS, launch_chromium, logged_in_page
from tests.server.live import Live, start_live

sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is a dev dependency")
expect = sync_api.expect


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    yield from start_live("sqlite", tmp_path_factory.mktemp("corrections-dashboard"), poll_recheck_s=1.0)


def _stats(page: Any) -> dict[str, Any]:
    got: dict[str, Any] = page.evaluate("window.linemapStats")
    return got


def _at_version(page: Any, version: int) -> Callable[[], bool]:
    return lambda: bool(_stats(page).get("version") == version)


def test_a_loop_closure_redraws_in_place(live: Live, tmp_path: Path) -> None:
    rid, token = live.new_robot()
    with sync_api.sync_playwright() as p:
        browser = launch_chromium(p)
        page, errors = logged_in_page(browser, live.base_url, live.admin_token)
        expect(page.locator(f'[data-testid="robot-row"][data-robot-id="{rid}"]')).to_be_visible()
        page.goto(f"{live.base_url}/#/robots/{rid}")
        expect(page.get_by_test_id("map-canvas")).to_be_visible()
        expect(page.get_by_test_id("map-layer-keyframes")).to_be_checked()
        expect(page.get_by_test_id("map-layer-loopClosures")).to_be_checked()
        page.evaluate("window.__sameDocument = true")

        agent = AgentProcess(
            tmp_path / "robot.db",
            server=live.base_url,
            robot_id=rid,
            token=token,
            extra=["--source", "sim:loop-block", "--rate", "0", "--loop-closure", "--exit-at-end"],
        )
        try:
            wait_for(
                "the first keyframes on the page",
                lambda: (_stats(page).get("graph") or {}).get("keyframes", 0) > 0,
                300,
            )
            snapshots = _stats(page)["snapshots"]  # from here on, only deltas
            assert agent.proc.wait(600) == 0, agent.output()
        finally:
            agent.stop()
        with live.operator() as op:
            latest = op.get(f"/robots/{rid}/maps/latest").json()
        wait_for("the page at the server's version", lambda: _stats(page)["version"] == latest["version"], 60)
        st = _stats(page)
        assert page.evaluate("window.__sameDocument") is True, "the page was reloaded"
        assert st["snapshots"] == snapshots, "the corrections came as a new snapshot, not as deltas"
        graph = st["graph"]
        assert graph["corrections"] >= 1 and graph["moved_poses"] > 0
        assert graph["loop_closures"] == len(latest["loop_closures"]) >= 1
        assert graph["keyframes"] == len(latest["keyframes"])
        # the walls the page drew are the server's, moved ones included
        assert st["segments"] == len(latest["segments"])
        assert st["walls_sum"] == pytest.approx(sum(sum(s[1:]) for s in latest["segments"]), abs=1e-6)
        # the trajectory, corrected in place, is the server's (which moved its poses the same way)
        server = {row[0]: row[1:] for row in latest["trajectory"]}
        sample = st["trajectory_sample"]
        assert len(sample) > 20
        worst = max(
            max(
                abs(r[1] - server[r[0]][0]),
                abs(r[2] - server[r[0]][1]),
                abs(math.remainder(r[3] - server[r[0]][2], math.tau)),
            )
            for r in sample
        )
        assert worst < 1e-6, f"the page's trajectory is {worst} m off the server's"
        # the uncertainty readout and the layer switches
        expect(page.get_by_test_id("map-pose-sigma")).to_contain_text("±x")
        expect(page.get_by_test_id("map-pose-sigma")).to_contain_text("cm")
        page.get_by_test_id("map-fit").click()
        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(ARTIFACTS / "map-loop-closure.png"))
        page.get_by_test_id("map-layer-loopClosures").uncheck()
        page.get_by_test_id("map-layer-keyframes").uncheck()
        wait_for(
            "the layers off",
            lambda: not _stats(page)["layers"]["keyframes"] and not _stats(page)["layers"]["loopClosures"],
            10,
        )
        browser.close()
    assert not errors, errors


def _keyframe_per_pose(v: int, first: int, n: int, closure: list[int]) -> dict[str, Any]:
    """Map version ``v`` (a snapshot at 1, else a delta): ``n`` poses from stamp ``first`` on, a keyframe
    at each, one wall and the loop closure ``closure``."""
    return {
        "version": v,
        "base_version": v - 1 if v > 1 else None,
        "stamp_s": float(first + n),
        "segments": [[float(v), 0.0, 0.0, 1.0, 1.0]],
        "trajectory": [[float(s), 0.001 * s, 1.0, 0.0] for s in range(first, first + n)],
        "keyframes": [[float(k), float(k), 0.001 * k, 1.0, 0.0] for k in range(first, first + n)],
        "loop_closures": [closure],
    }


def test_a_row_of_a_keyframe_the_server_dropped_is_left_out_on_the_page(live: Live) -> None:
    """A keyframe per pose for 9,000 poses: the server keeps the keyframes its thinned trajectory owns
    (server/mapgraph.py prune_graph). A later correction's row for a dropped keyframe and a closure to it
    are left out by the page as by the server, so the page's graph stays the server's."""
    rid, token = live.new_robot()
    per = 1000

    def delta(v: int, first: int, n: int) -> dict[str, Any]:
        return _keyframe_per_pose(v, first, n, [first + n - 1, max(first - per, 0)])

    with live.client(token) as robot:
        for k in range(9):
            assert robot.post(f"/robots/{rid}/maps", json=delta(k + 1, k * per, per)).status_code == 200
    with sync_api.sync_playwright() as p:
        browser = launch_chromium(p)
        page, errors = logged_in_page(browser, live.base_url, live.admin_token)
        page.goto(f"{live.base_url}/#/robots/{rid}")
        expect(page.get_by_test_id("map-canvas")).to_be_visible()
        wait_for("the page at version 9", lambda: _stats(page).get("version") == 9, 60)
        before = _stats(page)["graph"]
        correction = delta(10, 9 * per, 1) | {
            "keyframes": [[1.0, 1.0, 5.0, 5.0, 0.0], [0.0, 0.0, 0.0, 1.5, 0.0]],
            "loop_closures": [[9 * per - 1, 1], [9 * per - 1, 0]],
        }
        with live.client(token) as robot:
            assert robot.post(f"/robots/{rid}/maps", json=correction).status_code == 200
        wait_for("the page at version 10", lambda: _stats(page).get("version") == 10, 60)
        graph = _stats(page)["graph"]
        browser.close()
    with live.operator() as op:
        latest = op.get(f"/robots/{rid}/maps/latest").json()
    assert 1 not in {int(r[0]) for r in latest["keyframes"]}
    assert graph["keyframes"] == len(latest["keyframes"]) == before["keyframes"], "the dropped row left out"
    assert graph["loop_closures"] == len(latest["loop_closures"]) == before["loop_closures"] + 1
    assert graph["corrections"] == before["corrections"] + 1
    assert not errors, errors


def test_a_page_left_open_holds_the_keyframes_of_the_rows_it_holds(live: Live) -> None:
    """A page open while a robot sends a keyframe per pose: when the page drops its oldest trajectory rows
    (it holds the newest 5,000), the keyframes those rows owned and the loop closures reaching them go too
    (the server's rule, shared.protocol.keyframes_in_use), so a page left open for days stays bounded."""
    rid, token = live.new_robot()
    per, n_uploads = 500, 14

    def upload(v: int) -> dict[str, Any]:
        first = (v - 1) * per
        return _keyframe_per_pose(v, first, per, [max(first - 2 * per, 0), first + per - 1])

    with sync_api.sync_playwright() as p:
        browser = launch_chromium(p)
        page, errors = logged_in_page(browser, live.base_url, live.admin_token)
        with live.client(token) as robot:
            assert robot.post(f"/robots/{rid}/maps", json=upload(1)).status_code == 200
            page.goto(f"{live.base_url}/#/robots/{rid}")
            expect(page.get_by_test_id("map-canvas")).to_be_visible()
            wait_for("the page at version 1", lambda: _stats(page).get("version") == 1, 60)
            snapshots = _stats(page)["snapshots"]
            for v in range(2, n_uploads + 1):
                assert robot.post(f"/robots/{rid}/maps", json=upload(v)).status_code == 200
                wait_for(f"the page at version {v}", _at_version(page, v), 60)
        st = _stats(page)
        browser.close()
    assert st["snapshots"] == snapshots, "the page followed by deltas"
    # 7,000 rows sent; past 6,000 the page kept the newest 5,000 (1,500 on), then 500 more came
    first_row = st["trajectory_sample"][0][0]
    assert first_row == 1500.0
    graph = st["graph"]
    assert graph["keyframes"] == n_uploads * per - 1500, "the keyframes of the rows dropped are gone"
    kept = [(a, b) for a, b in (upload(v)["loop_closures"][0] for v in range(1, n_uploads + 1))]
    assert graph["loop_closures"] == sum(1 for a, b in kept if a >= 1500 and b >= 1500)
    assert not errors, errors
