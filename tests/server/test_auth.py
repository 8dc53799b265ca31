"""Who may call what: an endpoint-by-credential matrix generated from the route table (no credential, an
unknown token, an expired session, a revoked token, the robot's own token, another robot's token, an operator
token, an operator session), sessions, tokens, body limits and the audit log, all through the real server.
The brute-force limit (429) is tested in tests/reliability/test_rel_auth_limits.py."""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import timedelta
from typing import Any

import pytest
from fastapi.routing import APIRoute
from sqlalchemy import select

from server.app import ROUTERS
from server.csrf import CSRF_HEADER
from server.deps import SESSION_COOKIE, get_principal, require_operator, robot_access, robot_self
from server.models import Session as DbSession
from server.models import utcnow
from server.security import hash_token
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


def _call(
    live: Live,
    token: str | None,
    method: str,
    path: str,
    cookies: dict[str, str] | None = None,
    headers: dict[str, str] | None = None,
) -> tuple[int, str]:
    """(status, detail of an error) of one request. The brute-force limit is reset first: the matrix makes
    one failed attempt per route on purpose (the limit has its own tests in
    tests/reliability/test_rel_auth_limits.py)."""
    live.state.limiter.clear()
    with live.client(token, cookies=cookies) as c:
        c.headers.update(headers or {})
        url = path.removeprefix("/api/v1") if path.startswith("/api/v1") else live.base_url + path
        if method == "GET" and path.endswith("/stream"):
            with c.stream(method, url, timeout=10) as r:
                return r.status_code, (_detail(r.read()) if r.status_code >= 400 else "")
        r = c.request(method, url, params={"wait": 0})
        return r.status_code, (_detail(r.content) if r.status_code >= 400 else "")


def _detail(body: bytes) -> str:
    try:
        return str(json.loads(body).get("detail", ""))
    except (ValueError, AttributeError):
        return body.decode(errors="replace")


def test_every_route_is_protected_or_listed_public(live: Live) -> None:
    unprotected = [(m, p) for m, p, a in routes(live) if a == "UNPROTECTED"]
    assert unprotected == [], "add an auth dependency or list the route in PUBLIC"
    # The matrix covers every route the server serves: the OpenAPI document lists the same ones.
    served = {(m.upper(), p) for p, ops in live.app.openapi()["paths"].items() for m in ops}
    assert served == {(m, p) for m, p, _ in routes(live)}


# --------------------------------------------------------------------- the endpoint-by-credential matrix
#: Every credential a caller can present. "other-robot" is robot B's valid token on robot A's routes.
CREDENTIALS = [
    "none",
    "unknown-token",
    "expired-session",
    "revoked-token",
    "own-robot",
    "other-robot",
    "operator-token",
    "operator-session",
]
_REFUSED = {"none", "unknown-token", "expired-session", "revoked-token"}


def expected(credential: str, access: str) -> str | None:
    """What ``credential`` must get on a route with ``access``: "401", "403", "ok" (neither), or None
    (public routes: not checked)."""
    if access == "public":
        return None
    if credential in _REFUSED:
        return "401"
    if credential == "own-robot":
        return "403" if access == "operator" else "ok"
    if credential == "other-robot":
        return "ok" if access == "any" else "403"
    return "403" if access == "robot-self" else "ok"  # an operator


@dataclass
class Caller:
    """How to present one credential, and the robot whose routes are called."""

    token: str | None
    cookies: dict[str, str] | None
    robot_id: int
    detail: str  # part of the detail every 401/403 of this credential must contain
    headers: dict[str, str] | None = None  # a session's CSRF header, as the dashboard sends it


def _login_csrf(live: Live, token: str) -> tuple[str, dict[str, str]]:
    """(session id, the CSRF header of that session) from a login."""
    with live.client() as browser:
        r = browser.post("/session", json={"token": token})
        assert r.status_code == 200, r.text
        return str(r.cookies[SESSION_COOKIE]), {CSRF_HEADER: r.json()["csrf_token"]}


def _caller(live: Live, credential: str) -> Caller:
    rid, own = live.new_robot()
    if credential == "none":
        return Caller(None, None, rid, "no credential")
    if credential == "unknown-token":
        return Caller("lmo_not-a-real-token", None, rid, "unknown or revoked token")
    if credential == "expired-session":
        sid, csrf = _login_csrf(live, live.admin_token)
        with live.state.db.session() as s:  # white-box: the session's lifetime ends now
            row = s.scalars(select(DbSession).where(DbSession.token_hash == hash_token(sid))).one()
            row.expires_at = utcnow() - timedelta(seconds=1)
        live.state.forget_credentials()
        return Caller(None, {SESSION_COOKIE: sid}, rid, "session expired or unknown: log in again", csrf)
    if credential == "revoked-token":
        with live.operator() as op:
            made = op.post("/tokens", json={"name": "revoked"}).json()
            assert op.delete(f"/tokens/{made['id']}").status_code == 204
        return Caller(made["token"], None, rid, "unknown or revoked token")
    if credential == "own-robot":
        return Caller(own, None, rid, "this route is for operators")
    if credential == "other-robot":
        _other, theirs = live.new_robot()
        return Caller(theirs, None, rid, "not robot")  # "...belongs to robot B, not robot A" / "operators"
    if credential == "operator-token":
        return Caller(live.admin_token, None, rid, f"only robot {rid}'s own token")
    assert credential == "operator-session"
    sid, csrf = _login_csrf(live, live.admin_token)
    return Caller(None, {SESSION_COOKIE: sid}, rid, f"only robot {rid}'s own token", csrf)


@pytest.mark.parametrize("credential", CREDENTIALS)
def test_matrix(live: Live, credential: str) -> None:
    """Every route (from the route table) with every credential: refused with 401 or 403 and the reason,
    or let through, as ``expected`` says; a new route is in the matrix by construction."""
    caller = _caller(live, credential)
    wrong = []
    for method, path, access in routes(live):
        want = expected(credential, access)
        if want is None:
            continue
        code, detail = _call(
            live, caller.token, method, _fill(path, caller.robot_id), caller.cookies, caller.headers
        )
        ok = code not in (401, 403) if want == "ok" else code == int(want)
        if want == "403" and credential == "other-robot" and access == "operator":
            ok = ok and "this route is for operators" in detail
        elif want != "ok":
            ok = ok and caller.detail in detail
        if not ok:
            wrong.append((method, path, access, want, code, detail))
    assert wrong == [], f"{credential}: (method, path, access, expected, got, detail): {wrong}"


def test_session_cookie_login_and_logout(live: Live) -> None:
    with live.client() as browser:
        assert browser.post("/session", json={"token": "lmr_x"}).status_code == 401
        r = browser.post("/session", json={"token": live.admin_token})
        assert r.status_code == 200 and r.json()["kind"] == "operator"
        cookie = r.headers["set-cookie"].lower()
        assert "httponly" in cookie and "samesite=strict" in cookie
        assert browser.get("/robots").status_code == 200
        assert browser.delete("/session", headers={CSRF_HEADER: r.json()["csrf_token"]}).status_code == 204
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
