"""Cross-site request forgery with the session cookie, through the real server (:mod:`server.csrf`): every
state-changing route of the route table, each way a forged request can look (no token, a wrong token, a
token with another origin, ``Sec-Fetch-Site`` other than same-origin), is refused and changes nothing;
the dashboard's own requests and bearer clients go through. The browser-level attack (a page on another
port of 127.0.0.1) is in tests/server/dashboard/test_csrf_browser.py."""

from __future__ import annotations

import socket
import ssl
import threading
from pathlib import Path
from typing import Any

import httpx
import pytest
import uvicorn
from hypothesis import given
from hypothesis import strategies as st

from server.app import create_app
from server.bootstrap import ensure_admin_token
from server.csrf import CSRF_HEADER, csrf_token, normalize_origin, require_csrf_token
from server.deps import SESSION_COOKIE
from server.errors import ForbiddenError
from server.settings import Settings
from tests.robot_agent.agentproc import wait_for
from tests.server.live import Live, start_live
from tests.server.test_auth import _fill, routes

UNSAFE = {"POST", "PUT", "PATCH", "DELETE"}


def _session(live: Live) -> tuple[str, str]:
    """(session id, CSRF token) of a fresh operator login."""
    with live.client() as browser:
        r = browser.post("/session", json={"token": live.admin_token})
        assert r.status_code == 200, r.text
        sid = str(r.cookies[SESSION_COOKIE])
        assert r.json()["csrf_token"] == csrf_token(sid)
        return sid, r.json()["csrf_token"]


def _state(live: Live, rid: int) -> dict[str, Any]:
    """What a forged request could change, read with the operator's bearer token."""
    with live.operator() as op:
        return {
            "robot": op.get(f"/robots/{rid}").json()["last_seq"],
            "robots": sorted(r["id"] for r in op.get("/robots").json()),
            "audit": op.get("/audit", params={"limit": 1}).json()[0]["id"],
            "keys": op.get("/keys").json(),
            "kernels": op.get("/kernels", params={"deleted": True}).json(),
        }


def _forgeries(live: Live, token: str) -> dict[str, dict[str, str]]:
    other = live.base_url.rsplit(":", 1)[0] + ":1"  # another port of the same host: the same site
    return {
        "no token": {},
        "wrong token": {CSRF_HEADER: csrf_token("lms_someone-else")},
        "token, other origin": {CSRF_HEADER: token, "Origin": other},
        "token, origin null": {CSRF_HEADER: token, "Origin": "null"},
        "token, same-site": {CSRF_HEADER: token, "Sec-Fetch-Site": "same-site"},
        "token, cross-site": {CSRF_HEADER: token, "Sec-Fetch-Site": "cross-site"},
        "token, none": {CSRF_HEADER: token, "Sec-Fetch-Site": "none"},
        "token, own origin, same-site": {
            CSRF_HEADER: token,
            "Origin": live.base_url,
            "Sec-Fetch-Site": "same-site",
        },
    }


def _body(method: str, path: str) -> dict[str, Any]:
    """A request body the route would take, so a refusal is the guard's and not the body's."""
    if path.endswith("/messages"):
        return {
            "content": b"<xml><message><mode>offline</mode></message></xml>",
            "headers": {"Content-Type": "application/xml"},
        }
    if method == "POST" and path.endswith("/robots"):
        return {"json": {"name": "forged"}}
    if method == "POST" and path.endswith("/tokens"):
        return {"json": {"name": "forged"}}
    return {}


def test_every_state_changing_route_refuses_forged_cookie_requests(live: Live) -> None:
    rid, _ = live.new_robot()
    sid, token = _session(live)
    before = _state(live, rid)
    refused = []
    for method, path, _access in routes(live):
        if method not in UNSAFE or path.endswith("/session"):
            continue
        url = _fill(path, rid).removeprefix("/api/v1")
        for name, headers in _forgeries(live, token).items():
            live.state.limiter.clear()
            with live.client(cookies={SESSION_COOKIE: sid}) as browser:
                kw = _body(method, path)
                r = browser.request(method, url, **{**kw, "headers": {**kw.get("headers", {}), **headers}})
            assert r.status_code == 403, (method, path, name, r.status_code, r.text)
            reason = r.json().get("reason")
            assert reason in ("csrf", "cross-origin"), (method, path, name, r.text)
            refused.append((method, path, name))
    assert _state(live, rid) == before, "a forged request changed something"
    assert len(refused) >= 8 * 10  # every state-changing route, every forgery


def test_the_dashboard_own_requests_and_bearer_clients_go_through(live: Live) -> None:
    rid, _ = live.new_robot()
    sid, token = _session(live)
    body = b"<xml><message><mode>offline</mode></message></xml>"
    headers = {"Content-Type": "application/xml; charset=utf-8", CSRF_HEADER: token}
    with live.client(cookies={SESSION_COOKIE: sid}) as browser:
        # httpx sends neither Origin nor Sec-Fetch-Site: the token alone admits it
        plain = browser.post(f"/robots/{rid}/messages", content=body, headers=headers)
        assert plain.status_code == 201, plain.text
        assert plain.json()["created_by"] == "operator:admin"
        browser_like = {**headers, "Origin": live.base_url, "Sec-Fetch-Site": "same-origin"}
        r = browser.post(f"/robots/{rid}/messages", content=body, headers=browser_like)
        assert r.status_code == 201, r.text
        session = browser.get("/session").json()
        assert session == {"kind": "operator", "id": session["id"], "name": "admin", "csrf_token": token}
    # A bearer client needs no token, whatever Origin it sends (a browser cannot add Authorization itself).
    with live.operator() as op:
        r = op.post(
            f"/robots/{rid}/messages",
            content=body,
            headers={"Content-Type": "application/xml", "Origin": "http://elsewhere.example"},
        )
        assert r.status_code == 201, r.text
        assert op.get("/session").json()["csrf_token"] is None


def test_trusted_origin_setting_admits_a_proxy_origin(tmp_path: Path) -> None:
    for live in start_live("sqlite", tmp_path, csrf_trusted_origins=["https://linemap.example.org"]):
        rid, _ = live.new_robot()
        sid, token = _session(live)
        headers = {"Content-Type": "application/xml", CSRF_HEADER: token}
        body = b"<xml><message><mode>offline</mode></message></xml>"
        with live.client(cookies={SESSION_COOKIE: sid}) as browser:
            for origin, want in (
                ("https://linemap.example.org", 201),
                ("https://LINEMAP.example.org:443", 201),
                ("http://linemap.example.org", 403),
                ("https://linemap.example.org:8443", 403),
            ):
                r = browser.post(
                    f"/robots/{rid}/messages", content=body, headers={**headers, "Origin": origin}
                )
                assert r.status_code == want, (origin, r.text)
            r = browser.post(
                f"/robots/{rid}/messages", content=body, headers={**headers, "Origin": "http://evil.example"}
            )
            assert (
                "csrf_trusted_origins" in r.json()["detail"]
                and "https://linemap.example.org" in r.json()["detail"]
            )


def test_login_and_logout_from_another_origin_are_refused(live: Live) -> None:
    sid, token = _session(live)
    other = live.base_url.rsplit(":", 1)[0] + ":1"
    with live.client() as browser:
        r = browser.post("/session", json={"token": live.admin_token}, headers={"Origin": other})
        assert r.status_code == 403 and "Set-Cookie" not in r.headers, r.text
    with live.client(cookies={SESSION_COOKIE: sid}) as browser:
        assert browser.delete("/session").status_code == 403  # no token: the session stays
        assert (
            browser.delete(
                "/session", headers={CSRF_HEADER: token, "Sec-Fetch-Site": "same-site"}
            ).status_code
            == 403
        )
        assert browser.get("/robots").status_code == 200
        assert browser.delete("/session", headers={CSRF_HEADER: token}).status_code == 204
        assert browser.get("/robots").status_code == 401


def test_the_cookie_holds_session_ids_only(live: Live) -> None:
    """A raw operator (or robot) token in the cookie is refused, on reads and changes alike."""
    _rid, robot_token = live.new_robot()
    for value in (live.admin_token, robot_token, "Bearer " + live.admin_token, "x"):
        live.state.limiter.clear()
        with live.client(cookies={SESSION_COOKIE: value}) as browser:
            r = browser.get("/robots")
            assert r.status_code == 401 and "session id" in r.json()["detail"], (value, r.text)
            r = browser.post("/robots", json={"name": "via-cookie"}, headers={CSRF_HEADER: csrf_token(value)})
            assert r.status_code == 401, (value, r.text)
    live.state.limiter.clear()


def _self_signed(directory: Path) -> tuple[Path, Path]:
    """A throw-away certificate for 127.0.0.1 (cert file, key file)."""
    import datetime
    import ipaddress

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "127.0.0.1")])
    now = datetime.datetime.now(datetime.UTC)
    cert = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(hours=1))
        .add_extension(
            x509.SubjectAlternativeName([x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]), False
        )
        .sign(key, hashes.SHA256())
    )
    cert_file, key_file = directory / "cert.pem", directory / "key.pem"
    cert_file.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    key_file.write_bytes(
        key.private_bytes(
            serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
        )
    )
    return cert_file, key_file


def test_session_cookie_is_secure_over_https(tmp_path: Path) -> None:
    """A real uvicorn serving TLS on 127.0.0.1: the login cookie is Secure without any setting, and the
    dashboard's origin check uses the https origin."""
    cert, key = _self_signed(tmp_path)
    app = create_app(Settings(database_url=f"sqlite:///{tmp_path / 's.db'}"))
    admin = ensure_admin_token(app.state.linemap.db)
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    port = sock.getsockname()[1]
    config = uvicorn.Config(app, log_level="warning", ssl_certfile=str(cert), ssl_keyfile=str(key))
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    try:
        wait_for("uvicorn with TLS", lambda: server.started or not thread.is_alive())
        base = f"https://127.0.0.1:{port}"
        with httpx.Client(
            base_url=base + "/api/v1", verify=ssl.create_default_context(cafile=str(cert)), timeout=30
        ) as browser:
            r = browser.post("/session", json={"token": admin})
            assert r.status_code == 200, r.text
            assert (
                "secure" in r.headers["set-cookie"].lower() and "httponly" in r.headers["set-cookie"].lower()
            )
            csrf = {CSRF_HEADER: r.json()["csrf_token"]}
            good = browser.post("/robots", json={"name": "tls"}, headers={**csrf, "Origin": base})
            assert good.status_code == 201, good.text
            plain = browser.post(
                "/robots", json={"name": "tls2"}, headers={**csrf, "Origin": f"http://127.0.0.1:{port}"}
            )
            assert plain.status_code == 403, plain.text  # http:// is another origin than https://
    finally:
        server.should_exit = True
        thread.join(10)
        sock.close()


def test_session_cookie_secure_setting_and_plain_http(live: Live, tmp_path: Path) -> None:
    """Plain HTTP: not Secure by default (the browser would drop it), Secure when the setting says so (TLS
    ends at a proxy that forwards plain HTTP)."""
    with live.client() as browser:
        r = browser.post("/session", json={"token": live.admin_token})
        assert "secure" not in r.headers["set-cookie"].lower()
    for forced in start_live("sqlite", tmp_path, secure_cookies=True):
        with forced.client() as browser:
            r = browser.post("/session", json={"token": forced.admin_token})
            assert "secure" in r.headers["set-cookie"].lower()


@given(st.text(max_size=80))
def test_normalize_origin_never_raises_and_is_idempotent(text: str) -> None:
    out = normalize_origin(text)
    if out is not None:
        assert normalize_origin(out) == out
        assert out.startswith(("http://", "https://")) and out == out.lower()


@pytest.mark.parametrize(
    ("origin", "expected"),
    [
        ("http://127.0.0.1:8000", "http://127.0.0.1:8000"),
        ("HTTP://LocalHost:80", "http://localhost"),
        ("https://a.example:443/", "https://a.example"),
        ("http://[::1]:9", "http://[::1]:9"),
        ("null", None),
        ("file://", None),
        ("http://a.example/path", None),
        ("http://user@a.example", None),
        ("http://a.example:99999", None),
        ("ftp://a.example", None),
    ],
)
def test_normalize_origin(origin: str, expected: str | None) -> None:
    assert normalize_origin(origin) == expected


@given(
    st.text(min_size=1, max_size=60),
    st.text(max_size=60),
    st.sampled_from(["POST", "DELETE", "PUT", "patch"]),
)
def test_only_the_session_own_token_passes(session_tail: str, presented: str, method: str) -> None:
    sid = "lms_" + session_tail
    require_csrf_token(method, sid, csrf_token(sid))
    require_csrf_token("GET", sid, None)  # reads need none
    if presented.strip() != csrf_token(sid):
        with pytest.raises(ForbiddenError) as exc:
            require_csrf_token(method, sid, presented)
        assert CSRF_HEADER in str(exc.value) and exc.value.extra["reason"] == "csrf"
    assert csrf_token(sid) != csrf_token(sid + "x") and sid not in csrf_token(sid)
