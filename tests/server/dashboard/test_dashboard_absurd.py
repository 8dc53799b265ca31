"""The dashboard's live map in a real browser (Debian's Chromium) for stored maps no robot should have
sent: walls at 1e20 m and 1e300 m, and 130,000 long overlapping walls. The tab stays alive and answers
input: scripts evaluate, buttons click and a new frame follows; the big map's first frame is drawn and
its drawing completes in slices. Frame figures are printed, not asserted (benchmarks/dashboard_big_map.py)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.server.dashboard.absurd import login, store_absurd_map, store_big_map
from tests.server.dashboard.browser import launch_chromium
from tests.server.live import Live, start_live

sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is a dev dependency")
expect = sync_api.expect

ANSWER_MS = 15_000  # a hung tab never answers; a live one does (a deadline, not a timing assertion)


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    yield from start_live("sqlite", tmp_path_factory.mktemp("absurd"))


@pytest.fixture(scope="module")
def page(server: Live) -> Iterator[Any]:
    problems: list[str] = []
    with sync_api.sync_playwright() as p:
        browser = launch_chromium(p)
        context = browser.new_context(viewport={"width": 1280, "height": 800})
        pg = context.new_page()
        pg.set_default_timeout(30_000)
        pg.on("crash", lambda _page: problems.append("the tab crashed"))
        pg.on("pageerror", lambda exc: problems.append(f"page error: {exc}"))
        login(pg, server)
        yield pg
        context.close()
        browser.close()
    assert not problems, problems


def _new_frame_after(page: Any, action: Any) -> None:
    """Run ``action`` and wait (with a deadline) until the page has drawn a frame after it."""
    before = page.evaluate("window.linemapStats.drawn_at")
    action()
    page.wait_for_function("(b) => window.linemapStats.drawn_at > b", arg=before, timeout=ANSWER_MS)


def test_absurd_coordinates_neither_crash_nor_freeze_the_tab(page: Any, server: Live) -> None:
    rid = store_absurd_map(server)
    page.goto(f"{server.base_url}/#/robots/{rid}")
    page.wait_for_function(
        "() => window.linemapStats && window.linemapStats.version === 3"
        " && window.linemapStats.walls_complete",
        timeout=ANSWER_MS,
    )
    assert page.evaluate("1 + 1") == 2
    expect(page.get_by_test_id("map-walls")).to_have_text("6")
    far = page.get_by_test_id("map-far")
    expect(far).to_be_visible()
    expect(far).to_contain_text("3 walls not drawn")
    # the view was fitted to what is drawable: the room is on screen, not a 1e20 m extent
    scale = page.evaluate("document.querySelector('[data-testid=map-scale]').dataset.metres")
    assert float(scale) <= 2.0, scale
    _new_frame_after(page, lambda: page.get_by_test_id("map-fit").click(timeout=ANSWER_MS))
    _new_frame_after(page, lambda: page.get_by_title("Zoom out").click(timeout=ANSWER_MS))
    follow = page.get_by_test_id("map-follow")  # follow a robot whose pose is at -1e20 m
    _new_frame_after(page, lambda: follow.check(timeout=ANSWER_MS))
    _new_frame_after(page, lambda: page.get_by_title("Zoom in").click(timeout=ANSWER_MS))
    assert page.evaluate("window.linemapStats.walls_far") == 3


def test_130000_long_walls_draw_in_slices_and_the_page_answers(page: Any, server: Live) -> None:
    rid = store_big_map(server)
    page.goto(f"{server.base_url}/#/robots/{rid}")
    page.wait_for_function(
        "() => window.linemapStats && window.linemapStats.segments === 130000"
        " && window.linemapStats.walls_drawn > 0",
        timeout=60_000,
    )
    assert page.evaluate("1 + 1") == 2  # the page answers while the walls are still being drawn
    _new_frame_after(page, lambda: page.get_by_title("Zoom in").click(timeout=ANSWER_MS))
    canvas = page.get_by_test_id("map-canvas")
    box = canvas.bounding_box()
    assert box is not None

    def drag() -> None:
        page.mouse.move(box["x"] + 400, box["y"] + 300)
        page.mouse.down()
        page.mouse.move(box["x"] + 600, box["y"] + 420, steps=5)
        page.mouse.up()

    _new_frame_after(page, drag)
    page.wait_for_function("() => window.linemapStats.walls_complete", timeout=120_000)
    stats = page.evaluate("window.linemapStats")
    assert stats["walls_drawn"] > 0 and stats["walls_far"] == 0
    frames = stats["frame_ms"]
    print(
        f"130,000 walls: first frame {stats['first_frame_ms']:.0f} ms after the snapshot, "
        f"{len(frames)} frames, longest {max(frames):.1f} ms"
    )
    out = Path("test-artifacts/dashboard")
    out.mkdir(parents=True, exist_ok=True)
    page.screenshot(path=str(out / "big-map-130k.png"))
