"""The interactive API docs (:mod:`server.apidocs`) through the real server: off by default (the OpenAPI
document stays), and when turned on, a page whose CDN files are pinned by integrity hash under a strict
Content-Security-Policy; in Chromium, a CDN file that differs from the pinned one does not run."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from server.apidocs import SWAGGER_CSS, SWAGGER_JS
from tests.server.live import Live, start_live


@pytest.fixture(scope="module")
def docs_on(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Live]:
    yield from start_live("sqlite", tmp_path_factory.mktemp("docs-on"), api_docs=True)


def test_docs_are_off_by_default_and_the_openapi_document_stays(live: Live) -> None:
    with httpx.Client(base_url=live.base_url, timeout=30) as c:
        assert c.get("/docs").status_code == 404
        assert c.get("/redoc").status_code == 404
        doc = c.get("/openapi.json")
        assert doc.status_code == 200 and "/api/v1/robots" in doc.json()["paths"]


def test_docs_page_is_pinned_and_under_a_strict_policy(docs_on: Live) -> None:
    with httpx.Client(base_url=docs_on.base_url, timeout=30) as c:
        r = c.get("/docs", params={"html": "<script>alert(1)</script>", "url": "https://evil.example/x.json"})
        assert c.get("/redoc").status_code == 404
    assert r.status_code == 200
    assert "evil" not in r.text and "alert" not in r.text  # nothing of the request is reflected
    csp = r.headers["content-security-policy"]
    assert "default-src 'none'" in csp and "connect-src 'self'" in csp and "frame-ancestors 'none'" in csp
    assert f"script-src {SWAGGER_JS} 'sha256-" in csp and "unsafe-eval" not in csp
    for url in (SWAGGER_JS, SWAGGER_CSS):
        assert re.search(rf'"{re.escape(url)}" integrity="sha384-[A-Za-z0-9+/]{{64}}" crossorigin', r.text), (
            url
        )
    assert re.search(r"@\d+\.\d+\.\d+/", SWAGGER_JS), "an exact version, not a floating one"
    assert r.headers["x-content-type-options"] == "nosniff"


def test_a_cdn_file_that_differs_from_the_pinned_one_does_not_run(docs_on: Live, tmp_path: Path) -> None:
    """Chromium loads the page with the CDN answered by the test: a tampered bundle is refused by its
    integrity hash, so the page's own start-up script fails too (nothing from the CDN ran)."""
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is a dev dependency")
    from tests.server.dashboard.browser import launch_chromium

    with sync_api.sync_playwright() as p:
        browser = launch_chromium(p)
        page = browser.new_page()
        messages: list[str] = []
        page.on("console", lambda m: messages.append(m.text))
        page.on("pageerror", lambda e: messages.append(f"pageerror: {e}"))
        page.route(
            "https://cdn.jsdelivr.net/**",
            lambda route: route.fulfill(
                status=200,
                body="window.tampered = true; window.SwaggerUIBundle = () => { window.tampered = 2; };",
                headers={"Content-Type": "application/javascript", "Access-Control-Allow-Origin": "*"},
            ),
        )
        page.goto(docs_on.base_url + "/docs")
        page.wait_for_function("document.readyState === 'complete'")
        tampered = page.evaluate("window.tampered === undefined ? null : window.tampered")
        browser.close()
    assert tampered is None, messages
    assert any("integrity" in m for m in messages), messages
