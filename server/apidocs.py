"""The interactive API docs (``/docs``, Swagger UI): off by default; ``/redoc`` is not served.

No Python package ships Swagger UI in a version that reads this server's OpenAPI 3.1 document
(swagger-ui-bundle carries 4.15), so it comes from a CDN. Code from a CDN running in the API's own origin
could do anything the logged-in operator can (the session cookie goes with its requests), so the page is
served only when the operator turns it on (setting ``api_docs``, ``LINEMAP_API_DOCS=true``); its script
and style sheet are pinned to an exact version with their Subresource-Integrity hashes (the browser refuses
a file that differs); and it carries a strict Content-Security-Policy: scripts and styles only from those
two URLs plus the one inline start-up script by its hash, requests only to this server, no framing, no
form posts elsewhere. ``/openapi.json`` (the document itself) is always served. ReDoc is left out: ReDoc 2
fails on this document's ``$defs`` and ReDoc 3 ships no classic-script bundle. See docs/reliability/csrf.md.
"""

from __future__ import annotations

import base64
import hashlib
import json
from collections.abc import Callable

from fastapi import FastAPI
from fastapi.responses import HTMLResponse

__all__ = ["DOCS_PATH", "SWAGGER_CSS", "SWAGGER_JS", "docs_page", "mount"]

DOCS_PATH = "/docs"
_SWAGGER_UI = "https://cdn.jsdelivr.net/npm/swagger-ui-dist@5.32.0"
SWAGGER_JS = f"{_SWAGGER_UI}/swagger-ui-bundle.js"
SWAGGER_CSS = f"{_SWAGGER_UI}/swagger-ui.css"
#: sha384 of each pinned file, computed from the npm package swagger-ui-dist 5.32.0.
_SRI = {
    SWAGGER_JS: "sha384-7xcoc6ZKDFF7Ek627QTC3Bg/K+5Y36NJ8MWAE43D2m6+3Sh9XO3tdsfHhrS8gNIQ",
    SWAGGER_CSS: "sha384-3nuX7df3EaAoiqLBeyS1Ola0Gpg9ryJKVtarubwfnA1cOH8AWHUdbPSIvEqPZ9VH",
}


def docs_page(openapi_url: str) -> tuple[str, dict[str, str]]:
    """(HTML, headers) of the Swagger UI page reading ``openapi_url``."""
    script = f'SwaggerUIBundle({{url: {json.dumps(openapi_url)}, dom_id: "#swagger-ui", deepLinking: true}});'
    digest = base64.b64encode(hashlib.sha256(script.encode()).digest()).decode()
    html = (
        '<!doctype html><html lang="en"><head><meta charset="utf-8"><title>linemap API</title>'
        f'<link rel="stylesheet" href="{SWAGGER_CSS}" integrity="{_SRI[SWAGGER_CSS]}" '
        'crossorigin="anonymous">'
        '</head><body><div id="swagger-ui"></div>'
        f'<script src="{SWAGGER_JS}" integrity="{_SRI[SWAGGER_JS]}" crossorigin="anonymous"></script>'
        f"<script>{script}</script></body></html>"
    )
    csp = (
        f"default-src 'none'; script-src {SWAGGER_JS} 'sha256-{digest}'; "
        f"style-src {SWAGGER_CSS} 'unsafe-inline'; img-src 'self' data:; connect-src 'self'; "
        "object-src 'none'; base-uri 'none'; frame-ancestors 'none'; form-action 'self'"
    )
    headers = {
        "Content-Security-Policy": csp,
        "X-Content-Type-Options": "nosniff",
        "Referrer-Policy": "no-referrer",
        "Cache-Control": "no-cache",
    }
    return html, headers


def _endpoint(html: str, headers: dict[str, str]) -> Callable[[], HTMLResponse]:
    """A parameterless endpoint (FastAPI would read an endpoint's parameters from the query string)."""

    def docs() -> HTMLResponse:
        return HTMLResponse(html, headers=headers)

    return docs


def mount(app: FastAPI) -> None:
    """Serve ``/docs`` on ``app`` (called when the setting ``api_docs`` is on)."""
    html, headers = docs_page(app.openapi_url or "/openapi.json")
    app.add_api_route(
        DOCS_PATH,
        _endpoint(html, headers),
        methods=["GET"],
        include_in_schema=False,
        response_class=HTMLResponse,
    )
