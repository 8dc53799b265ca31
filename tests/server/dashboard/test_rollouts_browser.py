"""The Rollouts page in a real browser (Debian's Chromium via Playwright) against a real uvicorn server, with
robots simulated over HTTP: start a rollout from the form, pause it (the canary is still judged, no wave
goes out), resume, abort (every robot that got the update is rolled back), each robot's state and reason
on screen."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from shared.signing import generate_keypair
from tests.server.dashboard.absurd import login
from tests.server.dashboard.browser import ARTIFACTS, launch_chromium
from tests.server.live import Live, start_live
from tests.server.rolloutsim import OLD, SimRobot, healthy, upload_kernel

sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is a dev dependency")
expect = sync_api.expect


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    yield from start_live("sqlite", tmp_path_factory.mktemp("rollouts-browser"), rollout_tick_s=0.05)


@pytest.fixture(scope="module")
def page(live: Live) -> Iterator[Any]:
    errors: list[str] = []
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    with sync_api.sync_playwright() as p:
        browser = launch_chromium(p)
        context = browser.new_context(viewport={"width": 1280, "height": 900})
        pg = context.new_page()
        pg.set_default_timeout(30_000)
        pg.on("pageerror", lambda exc: errors.append(f"page error: {exc}"))
        yield pg
        context.close()
        browser.close()
    assert not errors, errors


def until(what: str, check: Callable[[], bool], serve: Callable[[], None]) -> None:
    """Serve the simulated robots until ``check`` holds (a readiness wait, not a timing assertion)."""
    deadline = time.monotonic() + 60
    while not check():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        serve()
        time.sleep(0.05)


def row_state(page: Any, robot: SimRobot) -> str:
    row = page.locator(f'[data-testid="rollout-robot-row"][data-robot-id="{robot.id}"]')
    return str(row.get_attribute("data-state") or "")


def test_start_pause_resume_abort_from_the_page(live: Live, page: Any) -> None:
    kernel = upload_kernel(live, generate_keypair())
    robots = [SimRobot(live) for _ in range(3)]
    canary, second, silent = robots

    def serve() -> None:
        canary.serve(healthy)
        second.serve(healthy)
        silent.poll()  # receives, never answers

    login(page, live)
    page.get_by_test_id("nav-rollouts").click()
    form_kernel = page.get_by_test_id("rollout-kernel")
    form_kernel.select_option(label=f"{kernel['name']}@{kernel['version']} (noise-removal)")
    page.get_by_test_id("rollout-wave-size").fill("2")
    page.get_by_test_id("rollout-window").fill("0.3")
    page.get_by_test_id("rollout-max-failures").fill("50")
    page.get_by_test_id("rollout-start").click()
    expect(page.get_by_test_id("rollout-state")).to_have_attribute("data-status", "running")
    page.get_by_test_id("rollout-pause").click()
    expect(page.get_by_test_id("rollout-state")).to_have_attribute("data-status", "paused")
    page.screenshot(path=str(ARTIFACTS / "rollout-paused.png"))

    until("the canary committed", lambda: row_state(page, canary) == "installed", serve)
    assert [row_state(page, r) for r in (second, silent)] == ["pending", "pending"], "no wave while paused"
    assert second.got == [] and silent.got == []

    page.get_by_test_id("rollout-resume").click()
    expect(page.get_by_test_id("rollout-state")).to_have_attribute("data-status", "running")
    until(
        "the second robot in its window", lambda: row_state(page, second) in ("applied", "installed"), serve
    )
    assert row_state(page, silent) == "sent"

    page.get_by_test_id("rollout-abort").click()
    expect(page.get_by_test_id("rollout-state")).to_have_attribute("data-status", "aborted")
    expect(page.get_by_test_id("rollout-stop-reason")).to_contain_text("aborted by operator:admin")
    until("the canary rolled back", lambda: row_state(page, canary) == "rolled-back", serve)
    reason = page.locator(f'[data-testid="rollout-robot-row"][data-robot-id="{canary.id}"]').get_by_test_id(
        "rollout-robot-reason"
    )
    expect(reason).to_contain_text("rollout aborted")
    assert row_state(page, second) == "rolled-back" and row_state(page, silent) == "sent"
    serve()
    assert (
        canary.got[-1][1].count("kernel-rollback") == 1
        and f'version="{OLD.split("@")[1]}"' in canary.got[-1][1]
    )
    page.screenshot(path=str(ARTIFACTS / "rollout-aborted.png"))

    page.get_by_test_id("nav-rollouts").click()
    row = page.locator('[data-testid="rollout-row"]').first
    expect(row).to_contain_text(f"{kernel['name']}@{kernel['version']}")
    expect(row).to_contain_text("aborted")


def test_the_form_says_what_is_wrong(live: Live, page: Any) -> None:
    upload_kernel(live, generate_keypair())  # the form is drawn only with a kernel and a robot to offer
    SimRobot(live)
    if not page.context.cookies():  # this module's page is logged in once, by whichever test runs first
        login(page, live)
    page.goto(live.base_url + "/#/robots")
    page.goto(live.base_url + "/#/rollouts")
    # the form arrives after the page's kernels and robots load, its boxes checked: wait for it before
    # unchecking them, or the boxes unchecked are none and the robots all go in the rollout
    expect(page.get_by_test_id("rollout-start")).to_be_visible()
    boxes = page.locator('input[type="checkbox"][data-testid^="rollout-robot-"]')
    assert boxes.count() >= 1
    for box in boxes.all():
        box.uncheck()
    page.get_by_test_id("rollout-start").click()
    expect(page.get_by_test_id("rollout-error")).to_contain_text("Choose at least one robot")
    boxes.first.check()
    page.get_by_test_id("rollout-canaries").fill("5")
    page.get_by_test_id("rollout-start").click()
    expect(page.get_by_test_id("rollout-error")).to_contain_text(
        "canaries 5 is more than the 1 robot of the rollout"
    )
    page.screenshot(path=str(ARTIFACTS / "rollouts-form.png"), full_page=True)


def test_every_robot_state_on_the_page(live: Live, page: Any) -> None:
    """A rollout with a canary, robots that reject, slow down and stay silent, and one still pending: each
    row shows its state and reason; the timed-out robot is marked as watched."""
    kernel = upload_kernel(live, generate_keypair())
    canary, rejecting, slow_one, silent, last = robots = [SimRobot(live) for _ in range(5)]
    held = {last.id}

    def slow(robot: SimRobot, seq: int, xml: str) -> None:
        robot.ack(seq, "applied")
        robot.report(active=f"{kernel['name']}@{kernel['version']}", step_ms=30.0)

    handlers = {
        canary.id: healthy,
        rejecting.id: lambda r, seq, xml: r.ack(seq, "rejected", "no space left for the kernel store"),
        slow_one.id: slow,
        silent.id: lambda r, seq, xml: None,
        last.id: healthy,
    }

    def serve() -> None:
        for robot in robots:
            if robot.id not in held:
                robot.serve(lambda r, seq, xml: handlers[r.id](r, seq, xml))

    body = {
        **kernel,
        "robots": [r.id for r in robots],
        "canaries": 1,
        "wave_size": 3,
        "max_failure_share": 0.8,
        "commit_window_s": 0.5,
        "ack_timeout_s": 5.0,  # the page shows the canary sent (not yet timed out) within this
        "watch_timeout_s": 600,
    }
    if not page.context.cookies():  # this module's page is logged in once, by whichever test runs first
        login(page, live)
    with live.operator() as op:
        r = op.post("/rollouts", json=body)
    assert r.status_code == 201, r.text
    rid = r.json()["id"]
    page.goto(f"{live.base_url}/#/rollouts/{rid}")
    canary_row = page.locator(f'[data-testid="rollout-robot-row"][data-robot-id="{canary.id}"]')
    expect(canary_row).to_have_attribute("data-state", "sent")
    expect(canary_row.locator("td").nth(1)).to_have_text("canary")
    assert [row_state(page, x) for x in robots[1:]] == ["pending"] * 4

    until("wave 1 decided", lambda: row_state(page, silent) == "timed-out", serve)
    assert row_state(page, canary) == "installed"
    assert row_state(page, last) == "sent", "wave 2 went out: 3 of 4 failed is within 80 %"

    def reason(robot: SimRobot) -> Any:
        row = page.locator(f'[data-testid="rollout-robot-row"][data-robot-id="{robot.id}"]')
        return row.get_by_test_id("rollout-robot-reason")

    expect(reason(rejecting)).to_have_text("rejected by the robot: no space left for the kernel store")
    assert row_state(page, rejecting) == "failed"
    expect(reason(slow_one)).to_contain_text("step time 30.0 ms is 3.00 x the 10.0 ms before the update")
    assert row_state(page, slow_one) == "rolled-back"
    expect(reason(silent)).to_contain_text("no acknowledgement within 5 s (offline or stuck?)")
    silent_row = page.locator(f'[data-testid="rollout-robot-row"][data-robot-id="{silent.id}"]')
    expect(silent_row).to_have_attribute("data-watched", "true")
    expect(silent_row.get_by_test_id("rollout-robot-watched")).to_have_text("watching for a late answer")

    held.clear()
    until("completed", lambda: row_state(page, last) == "installed", serve)
    expect(page.get_by_test_id("rollout-state")).to_have_attribute("data-status", "completed")
    expect(page.get_by_text("(watching robots still to answer)")).to_be_visible()
    page.screenshot(path=str(ARTIFACTS / "rollout-states.png"), full_page=True)
    page.get_by_test_id("nav-rollouts").click()
    row = page.locator(f'[data-testid="rollout-row"][data-rollout-id="{rid}"]')
    expect(row).to_contain_text("1 timed-out")
    expect(row).to_contain_text("1 rolled-back")
