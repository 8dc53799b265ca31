"""Cross-site request forgery in a real browser (Debian's Chromium via Playwright): the operator is logged
into the dashboard, and in the same browser a page served from ANOTHER port of 127.0.0.1 (the same site,
so the SameSite=Strict cookie goes along) tries every way a page can send a state-changing request: a
``text/plain`` and a typeless ``fetch`` with credentials to every state-changing route of the route table,
a ``fetch`` with JSON and a guessed CSRF header, and HTML form posts (``text/plain`` XML to the messages
route, url-encoded and multipart forms). Nothing is queued or changed, the server's guard saw and refused
the requests that reached it, and the dashboard's own buttons still work (also after a reload, when the
page fetches its CSRF token again)."""

from __future__ import annotations

import http.server
import json
import logging
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.robot_agent.agentproc import wait_for
from tests.server.dashboard.browser import launch_chromium
from tests.server.live import Live, start_live
from tests.server.test_auth import _fill, routes

sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is a dev dependency")
expect = sync_api.expect

XML = "<xml><message><mode>offline</mode></message></xml>"

#: The attacker's page: runs every forgery against the dashboard's server, then sets window.done.
ATTACK_JS = """
async function attack(base, targets, rid, xml) {
  const log = [];
  const note = (what, p) => p.then(() => log.push(what + ": sent"), (e) => log.push(what + ": blocked " + e));
  const jobs = [];
  for (const t of targets) {
    const url = base + t.path;
    if (t.method === "POST") {
      // "Simple" requests: no preflight, the cookie goes along.
      jobs.push(note(`text/plain ${t.method} ${t.path}`, fetch(url, { method: "POST", mode: "no-cors",
        credentials: "include", headers: { "Content-Type": "text/plain" }, body: xml })));
      jobs.push(note(`typeless ${t.method} ${t.path}`, fetch(url, { method: "POST", mode: "no-cors",
        credentials: "include", body: new Blob([t.json || xml]) })));
    }
    // Non-simple: JSON or XML typed, a guessed CSRF header, DELETE (a preflight, which must fail).
    jobs.push(note(`cors ${t.method} ${t.path}`, fetch(url, { method: t.method, mode: "cors",
      credentials: "include", headers: { "Content-Type": t.ctype, "X-Linemap-CSRF": "guess" },
      body: t.method === "POST" ? (t.json || xml) : undefined })));
  }
  await Promise.all(jobs);
  // HTML forms, each into its own frame.
  const form = (action, enctype, fields) => new Promise((resolve) => {
    const frame = document.createElement("iframe");
    frame.name = "f" + Math.random().toString(36).slice(2);
    document.body.append(frame);
    frame.addEventListener("load", () => resolve(), { once: true });
    const f = document.createElement("form");
    f.method = "POST"; f.action = action; f.enctype = enctype; f.target = frame.name;
    for (const [k, v] of Object.entries(fields)) {
      const i = document.createElement("input"); i.name = k; i.value = v; f.append(i);
    }
    document.body.append(f);
    f.submit();
  });
  // text/plain form: the body is "<xml>...<!--=-->", well-formed XML.
  await form(`${base}/robots/${rid}/messages`, "text/plain", { [xml + "<!--"]: "-->" });
  await form(`${base}/robots`, "application/x-www-form-urlencoded", { name: "forged-form" });
  await form(`${base}/tokens`, "multipart/form-data", { name: "forged-form" });
  await form(`${base}/kernels`, "multipart/form-data", { name: "k", stage: "clustering", version: "9.9.9",
    signature: "x", file: "print(1)" });
  log.push("forms: done");
  return log;
}
"""


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    yield from start_live("sqlite", tmp_path_factory.mktemp("csrf-browser"))


@pytest.fixture(scope="module")
def attacker(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """A plain http.server on another port of 127.0.0.1 serving the attacker's page."""
    root = tmp_path_factory.mktemp("attacker")
    (root / "evil.html").write_text(
        f"<!doctype html><html><body><h1>cat pictures</h1><script>{ATTACK_JS}</script></body></html>"
    )

    class Quiet(http.server.SimpleHTTPRequestHandler):
        def __init__(self, *a: Any, **kw: Any) -> None:
            super().__init__(*a, directory=str(root), **kw)

        def log_message(self, *_args: Any) -> None:
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Quiet)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}/evil.html"
    finally:
        server.shutdown()
        server.server_close()


def _targets(rid: int) -> list[dict[str, str]]:
    """Every state-changing route of the route table, with the body type it takes."""
    out = []
    for method, path, _access in routes():
        if method in ("GET", "HEAD", "OPTIONS"):
            continue
        filled = _fill(path, rid).removeprefix("/api/v1")
        t = {"method": method, "path": filled, "ctype": "application/json"}
        if filled.endswith("/messages"):
            t["ctype"] = "application/xml"
        elif method == "POST":
            t["json"] = json.dumps({"name": "forged", "token": "lmo_x", "outcome": "applied"})
        out.append(t)
    return out


def _snapshot(live: Live, rid: int) -> dict[str, Any]:
    with live.operator() as op:
        audit = op.get("/audit", params={"limit": 1000}).json()
        return {
            "last_seq": op.get(f"/robots/{rid}").json()["last_seq"],
            "robots": sorted((r["id"], r["name"]) for r in op.get("/robots").json()),
            "keys": op.get("/keys").json(),
            "kernels": op.get("/kernels", params={"deleted": True}).json(),
            "changes": [e for e in audit if e["action"] != "session.login"],
        }


def test_a_page_on_another_port_cannot_act_as_the_operator(
    live: Live, attacker: str, caplog: pytest.LogCaptureFixture, tmp_path: Path
) -> None:
    caplog.set_level(logging.WARNING, logger="server.csrf")
    rid, _ = live.new_robot()
    with sync_api.sync_playwright() as p:
        browser = launch_chromium(p)
        context = browser.new_context()
        dash = context.new_page()
        dash.set_default_timeout(30_000)
        dash.goto(live.base_url + "/")
        dash.get_by_test_id("login-token").fill(live.admin_token)
        dash.get_by_test_id("login-submit").click()
        expect(dash.locator(f'[data-testid="robot-row"][data-robot-id="{rid}"]')).to_be_visible()
        before = _snapshot(live, rid)

        evil = context.new_page()
        evil.goto(attacker)
        log = evil.evaluate(
            "([base, targets, rid, xml]) => attack(base, targets, rid, xml)",
            [live.base_url + "/api/v1", _targets(rid), rid, XML],
        )
        assert "forms: done" in log, log
        after = _snapshot(live, rid)
        assert after == before, f"a forged request changed something: {after} != {before}\n{log}"
        # The simple requests reached the server and its guard refused them (same-site, not same-origin).
        refused = " ".join(r.getMessage() for r in caplog.records if r.name == "server.csrf")
        assert f"POST /api/v1/robots/{rid}/messages" in refused and "Sec-Fetch-Site" in refused, refused
        assert "POST /api/v1/robots:" in refused and "POST /api/v1/tokens:" in refused, refused

        # The dashboard's own buttons still work: raw XML from the tuning tab, registering a robot, and
        # the same after a reload (the page has to fetch its CSRF token again), then logging out.
        def send_raw_xml() -> None:
            dash.goto(f"{live.base_url}/#/robots/{rid}")
            dash.get_by_test_id("tab-tune").click()
            dash.get_by_test_id("raw-xml").fill(XML)
            dash.get_by_test_id("raw-send").click()
            expect(dash.get_by_test_id("ack")).to_be_visible()

        def queued_messages() -> list[dict[str, Any]]:
            with live.operator() as op:
                messages: list[dict[str, Any]] = op.get(f"/robots/{rid}/messages").json()["messages"]
            return messages

        send_raw_xml()
        dash.reload()
        send_raw_xml()
        # The page may still show the first message's acknowledgement while the second POST is in flight:
        # wait until the server holds a second message (or the deadline passes), then check both.
        wait_for("the dashboard's second message", lambda: len(queued_messages()) >= 2 or None, 20.0)
        queued = queued_messages()
        assert [(m["seq"], m["created_by"]) for m in queued] == [(1, "operator:admin"), (2, "operator:admin")]
        dash.goto(f"{live.base_url}/#/robots")
        dash.get_by_test_id("register-name").fill("made-by-the-dashboard")
        dash.get_by_test_id("register-submit").click()
        expect(dash.get_by_test_id("register-token")).to_be_visible()
        dash.get_by_test_id("logout").click()
        expect(dash.get_by_test_id("login-token")).to_be_visible()
        dash.screenshot(path=str(tmp_path / "after-logout.png"))
        context.close()
        browser.close()
    with live.operator() as op:
        names = [r["name"] for r in op.get("/robots").json()]
        actions = [e["action"] for e in op.get("/audit", params={"limit": 5}).json()]
    assert "made-by-the-dashboard" in names and "forged" not in names and "forged-form" not in names
    assert actions[0] == "robot.register"
