"""Who may call what: an endpoint-by-credential matrix generated from the route table, sessions, tokens,
body limits and the audit log, all through the real server."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import pytest
from fastapi.routing import APIRoute

from server.app import ROUTERS
from server.deps import get_principal, require_operator, robot_access, robot_self
from tests.server.live import Live

PUBLIC = {
    ("GET", "/healthz"),
    ("GET", "/"),  # the dashboard page: static, no secrets; every API call it makes is checked
    ("GET", "/api/v1/schema/control.xsd"),
    ("POST", "/api/v1/session"),
    ("DELETE", "/api/v1/session"),
}


def _calls(dependant: Any) -> Iterator[Any]:
    for dep in dependant.dependencies:
        yield dep.call
        yield from _calls(dep)


def routes(live: Live | None = None) -> list[tuple[str, str, str]]:
    """(method, path, access) of every API route; access from its dependencies."""
    out = []
    for router, prefix in ROUTERS:
        for route in router.routes:
            assert isinstance(route, APIRoute)
            out += [
                (m, prefix + route.path, _access(route, m, prefix + route.path))
                for m in sorted(route.methods or ())
            ]
    return out


def _access(route: APIRoute, method: str, path: str) -> str:
    calls = set(_calls(route.dependant))
    if (method, path) in PUBLIC:
        return "public"
    for dep, access in (
        (robot_self, "robot-self"),
        (robot_access, "robot-or-operator"),
        (require_operator, "operator"),
        (get_principal, "any"),
    ):
        if dep in calls:
            return access
    return "UNPROTECTED"


def _fill(path: str, robot_id: int) -> str:
    return (
        path.replace("{robot_id}", str(robot_id))
        .replace("{seq}", "1")
        .replace("{name}", "no-such-kernel")
        .replace("{version}", "1.0.0")
        .replace("{token_id}", "999999")
        .replace("{kid}", "0" * 16)
    )


def _call(live: Live, token: str | None, method: str, path: str) -> int:
    with live.client(token) as c:
        url = path.removeprefix("/api/v1") if path.startswith("/api/v1") else live.base_url + path
        if method == "GET" and path.endswith("/stream"):
            with c.stream(method, url, timeout=10) as r:
                return r.status_code
        return c.request(method, url, params={"wait": 0}).status_code


def test_every_route_is_protected_or_listed_public(live: Live) -> None:
    unprotected = [(m, p) for m, p, a in routes(live) if a == "UNPROTECTED"]
    assert unprotected == [], "add an auth dependency or list the route in PUBLIC"
    # The matrix covers every route the server serves: the OpenAPI document lists the same ones.
    served = {(m.upper(), p) for p, ops in live.app.openapi()["paths"].items() for m in ops}
    assert served == {(m, p) for m, p, _ in routes(live)}


def test_matrix_without_credentials(live: Live) -> None:
    rid, _ = live.new_robot()
    for method, path, access in routes(live):
        if access == "public":
            continue
        assert _call(live, None, method, _fill(path, rid)) == 401, (method, path)
        assert _call(live, "lmo_not-a-real-token", method, _fill(path, rid)) == 401, (method, path)


def test_matrix_robot_tokens(live: Live) -> None:
    rid, token = live.new_robot()
    other, _ = live.new_robot()
    for method, path, access in routes(live):
        own = _call(live, token, method, _fill(path, rid))
        theirs = _call(live, token, method, _fill(path, other))
        if access == "operator":
            assert own == 403, (method, path)
        elif access in ("robot-self", "robot-or-operator"):
            assert own not in (401, 403), (method, path, own)
            assert theirs == 403, (method, path, theirs)
        elif access == "any":
            assert own not in (401, 403), (method, path, own)


def test_matrix_operator(live: Live) -> None:
    rid, _ = live.new_robot()
    for method, path, access in routes(live):
        if (method, path) == ("DELETE", "/api/v1/session"):
            continue
        code = _call(live, live.admin_token, method, _fill(path, rid))
        if access == "robot-self":
            assert code == 403, (method, path)
        else:
            assert code not in (401, 403), (method, path, code)


def test_session_cookie_login_and_logout(live: Live) -> None:
    with live.client() as browser:
        assert browser.post("/session", json={"token": "lmr_x"}).status_code == 401
        r = browser.post("/session", json={"token": live.admin_token})
        assert r.status_code == 200 and r.json()["kind"] == "operator"
        cookie = r.headers["set-cookie"].lower()
        assert "httponly" in cookie and "samesite=strict" in cookie
        assert browser.get("/robots").status_code == 200
        assert browser.delete("/session").status_code == 204
        assert browser.get("/robots").status_code == 401


def test_created_token_works_until_revoked(live: Live) -> None:
    with live.operator() as op:
        made = op.post("/tokens", json={"name": "night shift"}).json()
    with live.client(made["token"]) as c:
        assert c.get("/whoami").json() == {"kind": "operator", "id": made["id"], "name": "night shift"}
        assert c.delete(f"/tokens/{made['id']}").status_code == 204
        assert c.get("/robots").status_code == 401


def test_robot_token_is_shown_once_and_reaches_its_robot(live: Live) -> None:
    rid, token = live.new_robot()
    with live.operator() as op:
        listed = op.get("/robots").json()
        assert all("token" not in r for r in listed)
        assert any(r["id"] == rid for r in listed)
    with live.client(token) as robot:
        assert robot.get("/whoami").json()["kind"] == "robot"
        assert robot.get(f"/robots/{rid}").json()["id"] == rid


def test_duplicate_robot_name(live: Live) -> None:
    with live.operator() as op:
        assert op.post("/robots", json={"name": "twin-a"}).status_code in (201, 409)
        r = op.post("/robots", json={"name": "twin-a"})
        assert r.status_code == 409 and "twin-a" in r.json()["detail"]
        assert op.post("/robots", json={"name": ""}).status_code == 422


@pytest.mark.parametrize("chunked", [False, True])
def test_oversize_body_is_413(live: Live, chunked: bool) -> None:
    big = b'{"name": "' + b"x" * (300 * 1024) + b'"}'
    content: Any = iter([big[i : i + 65536] for i in range(0, len(big), 65536)]) if chunked else big
    with live.operator() as op:
        r = op.post("/robots", content=content, headers={"Content-Type": "application/json"})
    assert r.status_code == 413 and "limit" in r.json()["detail"]


def test_audit_log_records_operator_actions_newest_first(live: Live) -> None:
    rid, _ = live.new_robot()
    with live.operator() as op:
        op.post(
            f"/robots/{rid}/messages",
            content=b"<xml><message><mode>online</mode></message></xml>",
            headers={"Content-Type": "application/xml"},
        )
        entries = op.get("/audit", params={"limit": 50}).json()
    mine = [e for e in entries if e["target"] == f"robot:{rid}"]
    assert [e["action"] for e in mine] == ["message.post", "robot.register"]
    assert all(e["actor"] == "operator:admin" for e in mine)
    ids = [e["id"] for e in entries]
    assert ids == sorted(ids, reverse=True)
