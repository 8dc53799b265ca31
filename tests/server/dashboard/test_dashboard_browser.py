"""The operator dashboard in a real browser (Debian's Chromium via Playwright) against ``linemap demo``: a
real server and a real simulated robot agent on loopback.

The tests run in order on one page, as an operator would: log in, watch the live map, tune DBSCAN, send
Listing 1, upload / install / roll back a signed kernel, read the history, then draw a 5,000-wall map.
Screenshots and the measured latency and frame times are kept in ``test-artifacts/dashboard/``; the
figures are printed, not asserted (speed lives in the benchmarks: ``benchmarks/dashboard_latency.py``).
"""

from __future__ import annotations

import re
import statistics
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.robot_agent.agentproc import wait_for
from tests.server.dashboard.browser import (
    ARTIFACTS,
    launch_chromium,
    operator_client,
    running_demo,
    save_figures,
)

sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is a dev dependency")
expect = sync_api.expect

LISTING_1 = """<?xml version="1.0" encoding="UTF-8"?>
<xml>
 <message>
  <mode> online </mode>
  <noise-removal>
   <dbscan>
    <minpts> 3 </minpts>
    <epsilon> 5 </epsilon>
   </dbscan>
  </noise-removal>
  <clustering>
   <kmeans>
    <cluster-no> 50 </cluster-no>
   </kmeans>
  </clustering>
  <straight-line-method> Hough </straight-line-method>
 </message>
</xml>
"""

ACK_TIMEOUT_MS = 90_000


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Any]]:
    with running_demo(tmp_path_factory.mktemp("demo")) as info:
        yield info


@pytest.fixture(scope="module")
def page(demo: dict[str, Any]) -> Iterator[Any]:
    errors: list[str] = []
    with sync_api.sync_playwright() as p:
        browser = launch_chromium(p)
        context = browser.new_context(viewport={"width": 1280, "height": 800})
        pg = context.new_page()
        pg.set_default_timeout(30_000)
        pg.on("pageerror", lambda exc: errors.append(f"page error: {exc}"))
        pg.on(
            "console", lambda m: errors.append(f"console {m.type}: {m.text}") if m.type == "error" else None
        )
        yield pg
        context.close()
        browser.close()
    # A 4xx the page asked for on purpose shows as a console error in Chromium; scripts must not throw.
    assert not [e for e in errors if e.startswith("page error")], errors


def shot(page: Any, name: str) -> Path:
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    path = ARTIFACTS / f"{name}.png"
    page.screenshot(path=str(path))
    return path


def tid(page: Any, name: str) -> Any:
    return page.get_by_test_id(name)


def robot_state(demo: dict[str, Any]) -> dict[str, Any]:
    with operator_client(demo) as op:
        return dict(op.get(f"/robots/{demo['robot_id']}").json())


def open_robot(page: Any, demo: dict[str, Any]) -> None:
    page.goto(f"{demo['url']}#/robots/{demo['robot_id']}")
    expect(tid(page, "map-canvas")).to_be_visible()


def test_login_refuses_a_wrong_token_then_lists_the_robot(page: Any, demo: dict[str, Any]) -> None:
    page.goto(demo["url"])
    tid(page, "login-token").fill("lmo_not-a-real-token")
    tid(page, "login-submit").click()
    expect(tid(page, "login-error")).to_be_visible()
    expect(tid(page, "login-error")).not_to_be_empty()
    tid(page, "login-token").fill(demo["operator_token"])
    tid(page, "login-submit").click()
    row = page.locator(f'[data-testid="robot-row"][data-robot-id="{demo["robot_id"]}"]')
    expect(row).to_be_visible()
    expect(row).to_contain_text(demo["robot_name"])
    expect(row.get_by_test_id("robot-online")).to_contain_text("online")
    shot(page, "01-robots")


def test_live_map_grows_and_latency_is_measured(page: Any, demo: dict[str, Any]) -> None:
    open_robot(page, demo)
    version = tid(page, "map-version")
    expect(version).to_have_text(re.compile(r"^[1-9][0-9]*$"))
    first = int(version.inner_text())
    wait_for("the map to grow", lambda: int(version.inner_text()) >= first + 30, 60)
    walls = int(tid(page, "map-walls").inner_text())
    assert walls > 0
    # What the canvas drew is what the server holds (give or take the versions in flight).
    drawn = page.evaluate("window.linemapStats.version")
    assert abs(drawn - robot_state(demo)["map_version"]) < 100
    # The canvas is not blank: some pixels differ from the background.
    distinct = page.evaluate(
        """() => { const c = document.querySelector('[data-testid="map-canvas"]');
                   const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
                   const seen = new Set();
                   for (let i = 0; i < d.length; i += 4 * 97) seen.add(d[i] << 16 | d[i+1] << 8 | d[i+2]);
                   return seen.size; }"""
    )
    assert distinct > 3
    tid(page, "map-fit").click()
    wait_for(
        "300 latency samples", lambda: len(page.evaluate("window.linemapStats.latencies_ms")) >= 300, 120
    )
    lat = page.evaluate("window.linemapStats.latencies_ms")
    frames = page.evaluate("window.linemapStats.frame_ms")
    figures = {
        "step_to_canvas_ms": {
            "n": len(lat),
            "median": statistics.median(lat),
            "p95": sorted(lat)[int(0.95 * (len(lat) - 1))],
            "max": max(lat),
        },
        "frame_ms_live": {"n": len(frames), "median": statistics.median(frames), "max": max(frames)},
        "walls": walls,
    }
    print("dashboard live map:", figures)
    save_figures("live-map", figures)
    assert all(x > 0 for x in lat), "a step is drawn after it happened (clocks of one machine)"
    shot(page, "02-live-map")


def test_map_tools_pose_layers_measure_and_downloads(page: Any, demo: dict[str, Any]) -> None:
    """What people reach for on a map: a pose readout, layers switched off and on, a measured distance and
    angle, and the map downloaded as files of the version on screen."""
    open_robot(page, demo)
    expect(tid(page, "map-version")).to_have_text(re.compile(r"^[1-9][0-9]*$"))
    pose = re.compile(r"^x -?[0-9.]+ m · y -?[0-9.]+ m · heading [0-9.]+°$")
    expect(tid(page, "map-pose")).to_have_text(pose)

    # layers: centroids off, then on again; the frame drawn says which layers it drew
    tid(page, "map-layer-centroids").uncheck()
    drawn = "window.linemapStats.layers.centroids"
    wait_for("a frame without centroids", lambda: page.evaluate(drawn) is False)
    assert page.evaluate("window.linemapStats.layers.walls") is True
    tid(page, "map-layer-centroids").check()
    wait_for("centroids back", lambda: page.evaluate(drawn) is True)

    # measure: three clicks 150 px right, then 150 px up: a distance of 150 px in metres, bearing 0 deg,
    # and a right angle at the middle point
    tid(page, "map-measure").click()
    canvas = tid(page, "map-canvas")
    box = canvas.bounding_box()
    x0, y0 = box["width"] / 2 - 75, box["height"] / 2 + 75
    for dx, dy in ((0, 0), (150, 0), (150, -150)):
        canvas.click(position={"x": x0 + dx, "y": y0 + dy})
    scale = page.evaluate("window.linemapStats.scale")
    text = tid(page, "map-measure-text").inner_text()
    metres = re.match(r"^([0-9.]+) m · bearing ([0-9.]+)° · then ([0-9.]+) m · angle ([0-9.]+)°$", text)
    assert metres is not None, text
    assert abs(float(metres[1]) - 150 / scale) <= 0.011 and abs(float(metres[3]) - 150 / scale) <= 0.011
    assert float(metres[2]) in (0.0, 360.0) and abs(float(metres[4]) - 90.0) <= 0.1, text
    shot(page, "02b-measure")
    tid(page, "map-measure").click()
    expect(tid(page, "map-measure-readout")).to_be_hidden()

    # downloads: GeoJSON of the version on screen (or, said so, the current one), then PGM + YAML of one
    tid(page, "map-download").click()
    with page.expect_download() as got:
        tid(page, "map-download-geojson").click()
    name = got.value.suggested_filename
    assert name.endswith(".geojson"), name
    note = tid(page, "map-download-note")
    expect(note).to_contain_text(re.compile(r"(Downloaded map v[0-9]+|no longer held)"))
    tid(page, "map-download").click()
    with page.expect_download() as got:
        tid(page, "map-download-pgm+yaml").click()
    pgm = got.value.suggested_filename
    expect(note).to_contain_text(pgm.removesuffix(".pgm") + ".yaml")
    version = re.search(r"-map-v([0-9]+)-", pgm)
    assert version is not None, pgm
    # a version the server no longer holds: the current one is downloaded, and the note says so
    got = page.evaluate(
        """async (rid) => { const m = await import('/static/downloads.js');
                            return await m.downloadMap(rid, 'geojson', 1); }""",
        demo["robot_id"],
    )
    assert got["version"] > 1 and "map v1 is no longer held" in got["note"], got


def test_tuning_dbscan_epsilon_is_acknowledged_and_in_force(page: Any, demo: dict[str, Any]) -> None:
    open_robot(page, demo)
    tid(page, "tab-tune").click()
    field = tid(page, "param-noise-removal-0-epsilon_m")
    expect(field).to_be_visible()
    field.fill("0.04")
    tid(page, "tune-preview").click()
    expect(tid(page, "xml-preview")).to_contain_text("<epsilon")
    expect(tid(page, "xml-preview")).to_contain_text("0.04")
    shot(page, "03-tune-form")
    tid(page, "tune-send").click()
    ack = tid(page, "ack")
    expect(ack).to_have_attribute("data-status", "applied", timeout=ACK_TIMEOUT_MS)
    wait_for(
        "epsilon 0.04 in force on the robot",
        lambda: robot_state(demo)["config"]["noise_removal"][0]["params"].get("epsilon_m") == 0.04,
        60,
    )
    tid(page, "tab-status").click()
    cell = page.locator('[data-testid="config-table"] [data-kernel="dbscan"][data-param="epsilon_m"]')
    expect(cell).to_contain_text("0.04", timeout=30_000)
    shot(page, "04-tuned")


def test_loop_closure_switched_on_and_off_from_the_form(page: Any, demo: dict[str, Any]) -> None:
    open_robot(page, demo)
    tid(page, "tab-tune").click()
    tid(page, "tune-loop-enabled").check()
    tid(page, "tune-loop-radius").fill("5")
    tid(page, "tune-preview").click()
    expect(tid(page, "xml-preview")).to_contain_text("<loop-closure>")
    expect(tid(page, "xml-preview")).to_contain_text('<search-radius unit="m">5.0</search-radius>')
    tid(page, "tune-send").click()
    expect(tid(page, "ack")).to_have_attribute("data-status", "applied", timeout=ACK_TIMEOUT_MS)
    wait_for(
        "loop closure in force on the robot",
        lambda: (robot_state(demo)["config"].get("loop_closure") or {}).get("search_radius_m") == 5.0,
        60,
    )
    tid(page, "tab-status").click()
    row = page.locator('[data-testid="config-table"] [data-param="loop_closure"]')
    expect(row).to_contain_text("on", timeout=30_000)
    shot(page, "04b-loop-closure-on")
    # a value out of range is refused before anything is queued, naming the element
    before = robot_state(demo)["last_seq"]
    tid(page, "tab-tune").click()
    tid(page, "tune-loop-inliers").fill("1.5")
    tid(page, "tune-send").click()
    expect(tid(page, "form-error")).to_contain_text("min-inlier-share")
    assert robot_state(demo)["last_seq"] == before, "nothing was queued"
    # and off again
    tid(page, "tune-reset").click()
    tid(page, "tune-loop-enabled").uncheck()
    tid(page, "tune-send").click()
    expect(tid(page, "ack")).to_have_attribute("data-status", "applied", timeout=ACK_TIMEOUT_MS)
    wait_for("loop closure off", lambda: robot_state(demo)["config"].get("loop_closure") is None, 60)


def test_out_of_range_value_is_refused_with_its_name(page: Any, demo: dict[str, Any]) -> None:
    open_robot(page, demo)
    tid(page, "tab-tune").click()
    tid(page, "param-noise-removal-0-epsilon_m").fill("0.045")
    tid(page, "tune-send").click()
    expect(tid(page, "ack")).to_have_attribute("data-status", "applied", timeout=ACK_TIMEOUT_MS)
    before = robot_state(demo)["last_seq"]
    tid(page, "param-noise-removal-0-epsilon_m").fill("-1")
    tid(page, "tune-send").click()
    expect(tid(page, "form-error")).to_contain_text("epsilon")
    # the earlier "applied" panel is gone: under the error it would make the bad value look applied
    expect(tid(page, "ack")).to_be_hidden()
    assert robot_state(demo)["last_seq"] == before, "nothing was queued"


def test_listing_1_pasted_as_is(page: Any, demo: dict[str, Any]) -> None:
    open_robot(page, demo)
    tid(page, "tab-tune").click()
    tid(page, "tune-preview").click()
    expect(tid(page, "xml-preview")).to_be_visible()
    tid(page, "raw-xml").fill(LISTING_1)
    tid(page, "raw-send").click()
    expect(tid(page, "ack")).to_have_attribute("data-status", "applied", timeout=ACK_TIMEOUT_MS)
    expect(tid(page, "xml-preview")).to_be_hidden()  # the form's preview is not what was sent

    def in_force() -> bool:
        config = robot_state(demo)["config"]
        return bool(
            config["clustering"]["params"].get("n_clusters") == 50
            and config["straight_line"]["name"] == "hough"
            and config["noise_removal"][0]["params"].get("epsilon_m") == 0.05
        )

    wait_for("Listing 1 in force", in_force, 60)


def test_broken_xml_is_rejected_with_the_reason(page: Any, demo: dict[str, Any]) -> None:
    open_robot(page, demo)
    tid(page, "tab-tune").click()
    tid(page, "raw-xml").fill("<xml><message><mode>sideways</mode></message></xml>")
    tid(page, "raw-send").click()
    expect(tid(page, "form-error")).to_contain_text("mode")


def test_upload_install_and_roll_back_a_signed_kernel(page: Any, demo: dict[str, Any]) -> None:
    page.goto(f"{demo['url']}#/kernels")
    tid(page, "kernel-upload-file").set_input_files(demo["example_kernel"])
    tid(page, "kernel-upload-name").fill("dbscan")
    tid(page, "kernel-upload-stage").select_option("noise-removal")
    tid(page, "kernel-upload-version").fill("1.1.0")
    tid(page, "kernel-upload-signature").fill(demo["example_signature"])
    tid(page, "kernel-upload-submit").click()
    row = page.locator('[data-testid="kernel-row"][data-name="dbscan"][data-version="1.1.0"]')
    expect(row).to_be_visible()
    shot(page, "05-kernels")
    row.get_by_test_id("kernel-install").click()
    tid(page, "kernel-install-robot").select_option(str(demo["robot_id"]))
    tid(page, "kernel-install-confirm").click()
    expect(tid(page, "ack")).to_have_attribute("data-status", "applied", timeout=ACK_TIMEOUT_MS)
    wait_for(
        "dbscan 1.1.0 running",
        lambda: robot_state(demo)["active_kernels"].get("noise-removal") == "dbscan@1.1.0",
        60,
    )

    open_robot(page, demo)
    tid(page, "tab-kernels").click()
    mine = page.locator('[data-testid="robot-kernel-row"][data-name="dbscan"][data-version="1.1.0"]')
    expect(mine).to_have_attribute("data-state", "active", timeout=30_000)
    shot(page, "06-robot-kernels")
    mine.get_by_test_id("robot-kernel-rollback").click()
    tid(page, "rollback-version").select_option("1.0.0")
    tid(page, "rollback-confirm").click()
    expect(tid(page, "ack")).to_have_attribute("data-status", "applied", timeout=ACK_TIMEOUT_MS)
    wait_for(
        "dbscan 1.0.0 back",
        lambda: robot_state(demo)["active_kernels"].get("noise-removal") == "dbscan@1.0.0",
        60,
    )


def test_a_kernel_of_a_new_name_is_chosen_in_the_tune_form(page: Any, demo: dict[str, Any]) -> None:
    """The example radius-outlier filter (a kernel no built-in has the name of) is uploaded, installed,
    and chosen for the noise-removal chain in the Tune form; the message names it by <kernel name="..">
    and the robot runs it."""
    source = Path(demo["example_kernel"]).parent / "radius_outlier.py"
    page.goto(f"{demo['url']}#/kernels")
    tid(page, "kernel-upload-file").set_input_files(str(source))
    tid(page, "kernel-upload-name").fill("radius-outlier")
    tid(page, "kernel-upload-stage").select_option("noise-removal")
    tid(page, "kernel-upload-version").fill("1.0.0")
    tid(page, "kernel-upload-signature").fill(source.with_suffix(".sig").read_text().strip())
    tid(page, "kernel-upload-parameters-file").set_input_files(str(source.with_suffix(".params.json")))
    tid(page, "kernel-upload-submit").click()
    row = page.locator('[data-testid="kernel-row"][data-name="radius-outlier"][data-version="1.0.0"]')
    expect(row).to_be_visible()
    row.get_by_test_id("kernel-install").click()
    tid(page, "kernel-install-robot").select_option(str(demo["robot_id"]))
    tid(page, "kernel-install-confirm").click()
    expect(tid(page, "ack")).to_have_attribute("data-status", "applied", timeout=ACK_TIMEOUT_MS)

    open_robot(page, demo)
    tid(page, "tab-tune").click()
    tid(page, "tune-kernel-noise-removal-0").select_option("radius-outlier@1.0.0")
    # its parameters as fields, from the schema declared at upload, range-checked before anything is sent
    tid(page, "param-noise-removal-0-radius_m").fill("9")
    tid(page, "tune-send").click()
    expect(tid(page, "form-error")).to_contain_text("radius_m")
    tid(page, "param-noise-removal-0-radius_m").fill("0.06")
    tid(page, "param-noise-removal-0-min_neighbours").fill("2")
    tid(page, "tune-preview").click()
    expect(tid(page, "xml-preview")).to_contain_text('<kernel name="radius-outlier">')
    shot(page, "06b-tune-new-kernel")
    tid(page, "tune-send").click()
    expect(tid(page, "ack")).to_have_attribute("data-status", "applied", timeout=ACK_TIMEOUT_MS)
    wait_for(
        "radius-outlier running",
        lambda: robot_state(demo)["active_kernels"].get("noise-removal") == "radius-outlier@1.0.0",
        60,
    )
    params = robot_state(demo)["config"]["noise_removal"][0]["params"]
    assert params == {"radius_m": 0.06, "min_neighbours": 2}


def test_history_shows_audit_and_acknowledgements(page: Any, demo: dict[str, Any]) -> None:
    page.goto(f"{demo['url']}#/history")
    audit = tid(page, "audit-row")
    expect(audit.first).to_be_visible()
    actions = " ".join(audit.all_inner_texts())
    assert "kernel.upload" in actions and "message" in actions
    acks = tid(page, "ack-row")
    expect(acks.first).to_be_visible()
    texts = acks.all_inner_texts()
    assert any("applied" in t for t in texts), texts
    shot(page, "07-history")


def test_a_5000_wall_map_draws_in_full(page: Any, demo: dict[str, Any]) -> None:
    """A second robot with a 5,000-wall map (uploaded through the API, as a robot would) and 20 deltas
    moving 50 walls each; the page draws every wall. Frame times are recorded as figures."""
    import httpx

    with operator_client(demo) as op:
        r = op.post("/robots", json={"name": "big-map"})
        assert r.status_code == 201, r.text
        rid, token = r.json()["id"], r.json()["token"]
    segments = [
        [i, (i % 100) * 0.5, (i // 100) * 0.5, (i % 100) * 0.5 + 0.4, (i // 100) * 0.5 + 0.1]
        for i in range(5000)
    ]
    # 30 s: a 5,000-wall upload on a loaded 2-core machine can take longer than httpx's default 5 s
    auth = {"Authorization": f"Bearer {token}"}
    with httpx.Client(base_url=demo["url"] + "api/v1", headers=auth, timeout=30) as robot:
        snap = {"version": 1, "base_version": None, "segments": segments, "pose": [25.0, 12.0, 0.0]}
        assert robot.post(f"/robots/{rid}/maps", json=snap).status_code == 200
        page.goto(f"{demo['url']}#/robots/{rid}")
        expect(tid(page, "map-walls")).to_have_text("5000", timeout=30_000)
        page.evaluate("window.linemapStats.frame_ms.length = 0")
        for v in range(2, 22):
            moved = [
                [i, s[1], s[2] + 0.01 * v, s[3], s[4] + 0.01 * v] for i, s in enumerate(segments[: 50 * v])
            ][-50:]
            delta = {"version": v, "base_version": v - 1, "segments": moved, "pose": [25.0, 12.0, 0.1 * v]}
            assert robot.post(f"/robots/{rid}/maps", json=delta).status_code == 200
        expect(tid(page, "map-version")).to_have_text("21", timeout=30_000)
    expect(tid(page, "map-walls")).to_have_text("5000")
    frames = page.evaluate("window.linemapStats.frame_ms")
    figures = {"frames": len(frames), "median_ms": statistics.median(frames), "max_ms": max(frames)}
    print("dashboard 5,000-wall map:", figures)
    save_figures("big-map", figures)
    shot(page, "08-big-map")


def test_fleet_view_shows_every_robots_map_and_pose(page: Any, demo: dict[str, Any]) -> None:
    """Both robots (the demo's and the 5,000-wall one) with their maps drawn and their poses."""
    with operator_client(demo) as op:
        robots = op.get("/robots").json()
    page.goto(f"{demo['url']}#/fleet")
    cards = tid(page, "fleet-card")
    expect(cards).to_have_count(len(robots))
    sim = page.locator(f'[data-testid="fleet-card"][data-robot-id="{demo["robot_id"]}"]')
    expect(sim).not_to_have_attribute("data-version", "0")
    assert int(sim.get_attribute("data-drawn") or 0) > 0, "walls drawn in the card"
    pose = re.compile(r"^x -?[0-9.]+ m · y -?[0-9.]+ m · heading")
    expect(sim.get_by_test_id("fleet-pose")).to_have_text(pose)
    big = next(r for r in robots if r["name"] == "big-map")
    expect(page.locator(f'[data-testid="fleet-card"][data-robot-id="{big["id"]}"]')).to_have_attribute(
        "data-drawn", re.compile(r"^[1-9][0-9]{3}$")
    )
    shot(page, "09-fleet")
    sim.click()
    expect(tid(page, "map-canvas")).to_be_visible()
