"""415 for a request body whose Content-Type the route does not take (:mod:`server.mediatype`), on every
route of the route table through the real server: the answer names the type(s) the route takes, and a body
of the right type is not refused for its type."""

from __future__ import annotations

from fastapi.routing import APIRoute

from server.app import ROUTERS
from server.mediatype import accepted_media_types, media_type
from tests.server.live import Live
from tests.server.test_auth import _fill

_SAMPLE = {
    "application/json": b"{}",
    "application/xml": b"<xml><message><mode>offline</mode></message></xml>",
    "text/xml": b"<xml><message><mode>offline</mode></message></xml>",
    "multipart/form-data": b"--x--\r\n",
}


def _routes() -> list[tuple[str, str, APIRoute]]:
    return [
        (m, prefix + r.path, r)
        for router, prefix in ROUTERS
        for r in router.routes
        if isinstance(r, APIRoute)
        for m in sorted(r.methods or ())
    ]


def test_what_each_route_takes() -> None:
    taken = {(m, p): accepted_media_types(r) for m, p, r in _routes()}
    assert taken[("POST", "/api/v1/robots/{robot_id}/messages")] == ("application/xml", "text/xml")
    assert taken[("POST", "/api/v1/kernels")] == ("multipart/form-data",)
    assert taken[("POST", "/api/v1/robots")] == ("application/json",)
    assert taken[("POST", "/api/v1/robots/{robot_id}/maps")] == ("application/json",)
    assert taken[("POST", "/api/v1/session")] == ("application/json",)
    assert taken[("DELETE", "/api/v1/robots/{robot_id}")] == ()
    assert taken[("GET", "/api/v1/robots")] == ()
    assert media_type(" Application/XML ; charset=utf-8") == "application/xml"


def test_every_route_refuses_a_body_type_it_does_not_take(live: Live) -> None:
    rid, _ = live.new_robot()
    wrong = []
    for method, path, route in _routes():
        expected = list(accepted_media_types(route))
        url = live.base_url + _fill(path, rid)
        for token in (live.admin_token, None):
            with live.client(token) as c:
                for ctype in ("text/plain", "application/x-www-form-urlencoded", None, "application/jsonx"):
                    if ctype in expected:
                        continue
                    headers = {"Content-Type": ctype} if ctype else {}
                    r = c.request(method, url, content=b"<xml/>", headers=headers, params={"wait": 0})
                    if method == "HEAD":  # no body in the answer: the status says it
                        if r.status_code != 415:
                            wrong.append((method, path, ctype, r.status_code, ""))
                        continue
                    body = r.json() if r.headers.get("content-type") == "application/json" else {}
                    named = all(t in body.get("detail", "") for t in expected) or (
                        not expected and "takes no request body" in body.get("detail", "")
                    )
                    if r.status_code != 415 or body.get("expected") != expected or not named:
                        wrong.append((method, path, ctype, r.status_code, r.text[:200]))
    assert wrong == []


def test_a_body_of_a_type_the_route_takes_is_not_refused_for_its_type(live: Live) -> None:
    rid, _ = live.new_robot()
    with live.operator() as op:
        for ctype in ("application/xml", "text/xml", "application/xml; charset=utf-8", "TEXT/XML"):
            r = op.post(
                f"/robots/{rid}/messages", content=_SAMPLE["application/xml"], headers={"Content-Type": ctype}
            )
            assert r.status_code == 201, (ctype, r.text)
        r = op.post(
            "/robots",
            content=b'{"name": "typed"}',
            headers={"Content-Type": "application/json; charset=utf-8"},
        )
        assert r.status_code == 201, r.text
        # No body at all is not a media-type question: the route says what is missing.
        r = op.post("/robots")
        assert r.status_code == 422, r.text
        # The message is refused whatever XML it holds when the type is wrong: nothing queued.
        assert op.get(f"/robots/{rid}").json()["last_seq"] == 4
