"""schemathesis against the server's own OpenAPI document (docs/reliability.md): every operation of a real
uvicorn server (:func:`tests.server.live.start_live`) gets schema-valid and schema-violating requests with a
valid credential (the operator token; the robot's own token on robot-only routes), and none may answer
5xx. Fast part: ``LINEMAP_API_EXAMPLES`` (default 15) examples per operation and generation mode; soak:
``LINEMAP_SOAK_API_EXAMPLES`` (default 300).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import pytest
from fastapi.routing import APIRoute
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from server.app import ROUTERS
from server.deps import robot_self
from tests.server.live import Live, start_live

schemathesis = pytest.importorskip("schemathesis")
from schemathesis import GenerationMode  # noqa: E402
from schemathesis.config import SchemathesisConfig  # noqa: E402

FAST = int(os.environ.get("LINEMAP_API_EXAMPLES", 15))
SOAK = int(os.environ.get("LINEMAP_SOAK_API_EXAMPLES", 300))


def _calls(dependant: Any) -> Iterator[Any]:
    for dep in dependant.dependencies:
        yield dep.call
        yield from _calls(dep)


def operations() -> list[tuple[str, str, bool]]:
    """``(method, path, robot_only)`` of every API route, from the route table (as the auth matrix)."""
    out = []
    for router, prefix in ROUTERS:
        for route in router.routes:
            assert isinstance(route, APIRoute)
            robot_only = robot_self in set(_calls(route.dependant))
            out += [(m, prefix + route.path, robot_only) for m in sorted(route.methods or ())]
    return out


@dataclass
class Target:
    """The server under test and the credentials and robot the cases use (re-created if a case deletes
    them: a DELETE with a generated id may hit them)."""

    live: Live
    schema: Any
    robot_id: int
    robot_token: str
    operator_token: str
    protected_token_ids: tuple[int, ...]
    cases: int = 0
    codes: dict[int, int] = field(default_factory=dict)

    def renew(self) -> None:
        with self.live.client(self.operator_token) as op:
            r = op.post("/robots", json={"name": f"fuzz-{self.cases}"})
            assert r.status_code == 201, r.text
            self.robot_id, self.robot_token = int(r.json()["id"]), str(r.json()["token"])


@pytest.fixture(scope="module")
def target(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Target]:
    tmp = tmp_path_factory.mktemp("hostile-api-server")
    # long polls end at once (a generated wait=60 must not stall the run); small bodies keep it quick
    for live in start_live("sqlite", tmp, long_poll_max_s=0.01, max_body_bytes=256 * 1024):
        with live.operator() as op:
            made = op.post("/tokens", json={"name": "schemathesis"}).json()
            admin_id = int(op.get("/whoami").json()["id"])
        # an event stream is read up to its first event (the snapshot), not until the timeout
        config = SchemathesisConfig.from_dict({"max-stream-events": 1})
        schema = schemathesis.openapi.from_url(f"{live.base_url}/openapi.json", config=config)
        rid, token = live.new_robot()
        target = Target(live, schema, rid, token, made["token"], (admin_id, int(made["id"])))
        yield target
        print(f"\nschemathesis: {target.cases} requests, status codes {dict(sorted(target.codes.items()))}")


def _fix_ids(case: Any, method: str, path: str, t: Target, use_real: bool) -> None:
    """Point some cases at the existing robot (else nearly all are 404), never at our own credentials."""
    params = case.path_parameters or {}
    if "robot_id" in params and use_real and not (method == "DELETE" and path.endswith("{robot_id}")):
        params["robot_id"] = t.robot_id
    if path.endswith("/tokens/{token_id}") and params.get("token_id") in t.protected_token_ids:
        params["token_id"] = 1_000_000 + int(params["token_id"])


def _run(t: Target, method: str, path: str, robot_only: bool, examples: int) -> None:
    op = t.schema[path][method]
    strategy = op.as_strategy(GenerationMode.POSITIVE) | op.as_strategy(GenerationMode.NEGATIVE)

    @settings(
        max_examples=examples,
        deadline=None,
        suppress_health_check=list(HealthCheck),
        derandomize=False,
    )
    @given(case=strategy, use_real=st.booleans())
    def check(case: Any, use_real: bool) -> None:
        _fix_ids(case, method, path, t, use_real)
        token = t.robot_token if robot_only else t.operator_token
        response = case.call(
            base_url=t.live.base_url, headers={"Authorization": f"Bearer {token}"}, timeout=30
        )
        t.cases += 1
        status = response.status_code
        t.codes[status] = t.codes.get(status, 0) + 1
        assert status < 500, f"{method} {path} -> {status}: {response.text[:500]}\n{case.as_curl_command()}"
        deleted = method == "DELETE" and path == "/api/v1/robots/{robot_id}" and status == 204
        if deleted and case.path_parameters.get("robot_id") == t.robot_id:
            t.renew()
        rotated = method == "POST" and path == "/api/v1/robots/{robot_id}/token" and status == 201
        if rotated and case.path_parameters.get("robot_id") == t.robot_id:
            t.robot_token = str(response.json()["token"])  # the old one stopped working

    check()


@pytest.mark.parametrize(("method", "path", "robot_only"), operations(), ids=lambda v: str(v))
def test_no_server_errors(target: Target, method: str, path: str, robot_only: bool) -> None:
    _run(target, method, path, robot_only, FAST)


@pytest.mark.soak
@pytest.mark.parametrize(("method", "path", "robot_only"), operations(), ids=lambda v: str(v))
def test_no_server_errors_soak(target: Target, method: str, path: str, robot_only: bool) -> None:
    _run(target, method, path, robot_only, SOAK)


BIG = 2**63  # one past the largest database integer


@pytest.mark.parametrize(
    ("method", "path", "kwargs"),
    [
        ("GET", "/robots/{rid}/messages/{big}", {}),
        ("GET", "/robots/{big}", {}),
        ("DELETE", "/robots/{big}", {}),
        ("DELETE", "/tokens/{big}", {}),
        ("GET", "/robots/{rid}/messages", {"params": {"after": BIG}}),
        ("GET", "/robots/{rid}/maps/latest", {"params": {"trajectory": BIG}}),
        ("GET", "/audit", {"params": {"before": BIG}}),
        ("POST", "/robots/{rid}/maps", {"json": {"version": BIG}}),
        ("POST", "/robots/{rid}/maps", {"json": {"version": 2, "base_version": 1, "removed": [BIG]}}),
        ("POST", "/robots/{rid}/maps", {"json": {"version": 1, "segments": [[9.3e18, 0, 0, 1, 1]]}}),
    ],
)
def test_numbers_beyond_64_bits_are_422(
    target: Target, method: str, path: str, kwargs: dict[str, Any]
) -> None:
    """Findings of schemathesis, kept as cases: before the fix each was a 500 (OverflowError in the
    SQLite driver); now the bound is in the OpenAPI document and the answer a 422 naming the field."""
    robot = path.startswith("/robots/{rid}/maps") and method == "POST"
    token = target.robot_token if robot else target.operator_token
    url = path.format(rid=target.robot_id, big=BIG)
    with target.live.client(token) as c:
        r = c.request(method, url, **kwargs)
    assert r.status_code == 422, (method, url, r.status_code, r.text[:300])
    assert r.json()["detail"], r.text
