"""The robot page's Maps tab in a real browser (Debian's Chromium via Playwright) against a real server on
127.0.0.1: the robot's maps, one per mapping session (the replaced one kept, with its walls), and its
identity events: a new session and why, an agent that took over, one that was refused, and the message
numbering re-synchronised after a restore (each made here through the robot's own HTTP API)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from tests.server.dashboard.browser import ARTIFACTS, launch_chromium, logged_in_page
from tests.server.live import Live, start_live

sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is a dev dependency")
expect = sync_api.expect

S1, S2 = "11111111-1111-4111-8111-111111111111", "22222222-2222-4222-8222-222222222222"
A, B = "aaaaaaaa-aaaa-4aaa-8aaa-aaaaaaaaaaaa", "bbbbbbbb-bbbb-4bbb-8bbb-bbbbbbbbbbbb"


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    yield from start_live("sqlite", tmp_path_factory.mktemp("robotmaps-dashboard"))


def _snapshot(session: str, version: int, walls: int, reason: str) -> dict[str, object]:
    return {
        "map_session": session,
        "map_session_reason": reason,
        "version": version,
        "segments": [[i, float(i), 0.0, float(i), 1.0] for i in range(walls)],
        "trajectory": [[0.1, 0.0, 0.0, 0.0]],
    }


def _as_robot(live: Live, token: str, instance: str) -> httpx.Client:
    headers = {"Authorization": f"Bearer {token}", "X-Linemap-Agent-Instance": instance}
    return httpx.Client(base_url=live.base_url + "/api/v1", headers=headers, timeout=30.0)


def test_the_maps_tab_lists_sessions_and_identity_events(live: Live) -> None:
    rid, token = live.new_robot()
    with _as_robot(live, token, A) as a, _as_robot(live, token, B) as b:
        assert a.post(f"/robots/{rid}/maps", json=_snapshot(S1, 7, 3, "new Robot DB")).status_code == 200
        r = b.post(f"/robots/{rid}/maps", json=_snapshot(S2, 2, 1, "new Robot DB"))  # B takes over
        assert r.status_code == 200, r.text
        refused = a.get(f"/robots/{rid}/messages", params={"after": 0})
        assert refused.status_code == 409 and refused.json()["error"] == "agent_superseded"
        assert b.get(f"/robots/{rid}/messages", params={"after": 5}).status_code == 200  # resync to 5

    with sync_api.sync_playwright() as p:
        browser = launch_chromium(p)
        page, errors = logged_in_page(browser, live.base_url, live.admin_token)
        expect(page.locator(f'[data-testid="robot-row"][data-robot-id="{rid}"]')).to_be_visible()
        page.goto(f"{live.base_url}/#/robots/{rid}/maps")
        rows = page.get_by_test_id("map-session")
        expect(rows).to_have_count(2)
        expect(rows.nth(0)).to_have_attribute("data-session", S2)
        expect(rows.nth(0)).to_have_attribute("data-current", "true")
        expect(rows.nth(1)).to_have_attribute("data-session", S1)
        expect(rows.nth(1).get_by_test_id("session-walls")).to_have_text("3")
        expect(rows.nth(1).get_by_test_id("session-last-version")).to_have_text("7")
        events = page.get_by_test_id("robot-event")
        for action in ("map.session.start", "agent.takeover", "agent.refused", "messages.resync"):
            expect(page.locator(f'[data-testid="robot-event"][data-action="{action}"]').first).to_be_visible()
        expect(page.locator('[data-action="messages.resync"]')).to_contain_text("applied up to 5")
        assert events.count() >= 5
        ARTIFACTS.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(Path(ARTIFACTS) / "robot-maps.png"))
        browser.close()
    assert not errors, errors
