"""The live map's history slider (history_slider.js) in a real browser (Debian's Chromium via Playwright)
against a real uvicorn server on 127.0.0.1, the robot's uploads made over its own HTTP API: step and drag to
a version and see that version's walls and pose (as the API gives them), a live upload that does not
overwrite the view, a download of the version shown, replay to the end and back to live, and a version the
server no longer holds (a snapshot came since) refused on screen with the held range."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from tests.server.dashboard.absurd import login
from tests.server.dashboard.browser import ARTIFACTS, launch_chromium
from tests.server.live import Live, start_live

sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is a dev dependency")
expect = sync_api.expect


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    yield from start_live("sqlite", tmp_path_factory.mktemp("history-browser"))


@pytest.fixture(scope="module")
def page(live: Live) -> Iterator[Any]:
    errors: list[str] = []
    with sync_api.sync_playwright() as p:
        browser = launch_chromium(p)
        context = browser.new_context(viewport={"width": 1280, "height": 800}, accept_downloads=True)
        pg = context.new_page()
        pg.set_default_timeout(30_000)
        pg.on("pageerror", lambda exc: errors.append(f"page error: {exc}"))
        yield pg
        context.close()
        browser.close()
    assert not errors, errors


def _upload(robot: httpx.Client, rid: int, version: int, base: int | None, walls: int) -> None:
    """Version ``version``: walls 0..walls-1 (a delta moves wall 0 and adds one), pose at x=version."""
    segs = [[float(i), float(i), 0.0, float(i), 1.0 + 0.1 * version * (i == 0)] for i in range(walls)]
    body = {
        "version": version,
        "base_version": base,
        "stamp_s": 100.0 + version,
        "segments": segs if base is None else [segs[0], segs[-1]],
        "removed": [],
        "centroids": [],
        "pose": [float(version), 0.5, 0.0],
        "trajectory": [[100.0 + version, float(version), 0.5, 0.0]],
    }
    r = robot.post(f"/robots/{rid}/maps", json=body)
    assert r.status_code == 200, r.text


def _expect_shown(page: Any, op: httpx.Client, rid: int, version: int) -> None:
    """The map shows version ``version`` as the API rebuilds it: its number, wall count and pose."""
    m = op.get(f"/robots/{rid}/maps/latest", params={"version": version}).json()
    expect(page.get_by_test_id("map-version")).to_have_text(str(version))
    expect(page.get_by_test_id("map-walls")).to_have_text(str(len(m["segments"])))
    expect(page.get_by_test_id("map-pose")).to_contain_text(f"x {m['pose'][0]:.2f} m")
    page.wait_for_function(
        "([v, n]) => window.linemapStats.version === v && window.linemapStats.segments === n",
        arg=[version, len(m["segments"])],
    )


def test_step_drag_download_replay_and_live(live: Live, page: Any) -> None:
    rid, token = live.new_robot()
    with live.client(token) as robot:
        _upload(robot, rid, 1, None, 3)
        for v in range(2, 6):  # versions 2..5: 4..7 walls
            _upload(robot, rid, v, v - 1, v + 2)
    login(page, live)
    page.goto(f"{live.base_url}/#/robots/{rid}")
    label, rng = page.get_by_test_id("history-label"), page.get_by_test_id("history-range")
    with live.operator() as op:
        _expect_shown(page, op, rid, 5)
        expect(label).to_have_text("live · v5")
        expect(rng).to_have_attribute("max", "4")  # versions 1..5

        page.get_by_test_id("history-back").click()
        _expect_shown(page, op, rid, 4)
        expect(label).to_contain_text("v4 of 1..5")
        expect(page.get_by_test_id("history-live")).not_to_have_class("history-live active")

        rng.fill("1")  # drag to the second version
        _expect_shown(page, op, rid, 2)

        # the live stream keeps arriving, but the view stays on version 2
        with live.client(token) as robot:
            _upload(robot, rid, 6, 5, 8)
        page.wait_for_function("() => window.linemapStats.live_version === 6")
        _expect_shown(page, op, rid, 2)

        # downloads are of the version shown
        page.get_by_test_id("map-download").click()
        with page.expect_download() as got:
            page.get_by_test_id("map-download-geojson").click()
        assert got.value.suggested_filename == f"robot-{rid}-map-v2.geojson"
        saved = Path(got.value.path()).read_text()
        api_geo = op.get(f"/robots/{rid}/maps/export", params={"format": "geojson", "version": 2}).text
        assert saved == api_geo
        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(ARTIFACTS / "history-slider.png"))

        # replay at the fastest speed: through 3..6, then live again
        page.get_by_test_id("history-speed").select_option("10")
        page.get_by_test_id("history-play").click()
        expect(label).to_have_text("live · v6", timeout=30_000)
        expect(page.get_by_test_id("history-play")).to_have_text("Play")
        _expect_shown(page, op, rid, 6)

        # back in history, then the Live button
        page.get_by_test_id("history-back").click()
        _expect_shown(page, op, rid, 5)
        page.get_by_test_id("history-live").click()
        _expect_shown(page, op, rid, 6)
        expect(label).to_have_text("live · v6")

        # a version the server no longer holds: a snapshot (version 7) replaced the map since the list
        page.get_by_test_id("history-back").click()
        _expect_shown(page, op, rid, 5)
        with live.client(token) as robot:
            _upload(robot, rid, 7, None, 2)
        page.get_by_test_id("history-back").click()  # version 4, listed before the snapshot
        expect(label).to_contain_text("v4: version 4 of robot")
        expect(label).to_contain_text("7")  # the held range, 7 only now
        expect(label).to_have_class("history-label error")
        page.get_by_test_id("history-live").click()
        _expect_shown(page, op, rid, 7)
        expect(rng).to_have_attribute("max", "0")
