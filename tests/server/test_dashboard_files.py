"""The dashboard's files are served by the server itself, with a strict content security policy."""

from __future__ import annotations

import re

import httpx

from server.dashboard import STATIC_DIR
from tests.server.live import Live


def test_page_and_its_modules_are_served(live: Live) -> None:
    with httpx.Client(base_url=live.base_url) as browser:
        page = browser.get("/")
        assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
        csp = page.headers["content-security-policy"]
        assert "script-src 'self'" in csp and "frame-ancestors 'none'" in csp
        assert page.headers["x-content-type-options"] == "nosniff"
        scripts = re.findall(r'src="(/static/[^"]+)"', page.text)
        assert scripts, "the page loads its code from /static"
        for src in scripts:
            r = browser.get(src)
            assert r.status_code == 200, src
            assert "javascript" in r.headers["content-type"], (src, r.headers["content-type"])
        assert browser.get("/static/no-such-file.js").status_code == 404
        assert browser.get("/static/../server.db").status_code == 404


def test_every_module_the_page_imports_exists() -> None:
    """Relative ES-module imports resolve to files that are there (a typo would blank the page)."""
    for js in STATIC_DIR.rglob("*.js"):
        for target in re.findall(r"""^\s*import\s[^'"]*['"](\.[^'"]+)['"]""", js.read_text(), flags=re.M):
            assert (js.parent / target).resolve().is_file(), f"{js.name} imports missing {target}"


def test_the_upload_form_spells_versions_as_the_protocol_does() -> None:
    """The kernel upload form checks the version before sending it, with the protocol's pattern."""
    import json

    from shared.protocol import VERSION_PATTERN

    js = (STATIC_DIR / "views" / "kernels.js").read_text()
    found = re.search(r"^const VERSION_PATTERN = (\"[^\n]*\");$", js, flags=re.M)
    assert found is not None and json.loads(found.group(1)) == VERSION_PATTERN
