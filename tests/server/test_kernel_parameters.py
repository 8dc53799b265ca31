"""Kernel parameter schemas declared at upload (``parameters``, as ``linemap kernels --describe`` prints
it): kept with the artifact, and messages choosing that kernel are checked against it before they are
queued, naming the parameter; a bad declaration is refused at upload."""

from __future__ import annotations

import json
import subprocess
import sys
import uuid
from pathlib import Path
from typing import Any

import pytest

from shared.signing import KeyPair, generate_keypair, load_private_key, sha256_hex, sign_digest
from tests.server.live import Live

EXAMPLE = Path(__file__).parents[2] / "docs" / "examples" / "radius_outlier.py"
LINEMAP = str(Path(sys.executable).parent / "linemap")
XML = {"Content-Type": "application/xml"}


@pytest.fixture(scope="module")
def key() -> KeyPair:
    return generate_keypair()


@pytest.fixture(scope="module")
def schema() -> dict[str, Any]:
    """What the operator's tool prints for the example kernel (the file is imported there, not here)."""
    out = subprocess.run(
        [LINEMAP, "kernels", "--describe", str(EXAMPLE)], capture_output=True, text=True, check=True
    )
    assert "radius-outlier 1.0.0 (noise-removal)" in out.stderr
    declared: dict[str, Any] = json.loads(out.stdout)
    return declared


def _upload(live: Live, key: KeyPair, name: str, parameters: str | None) -> Any:
    source = EXAMPLE.read_bytes().replace(b'"radius-outlier"', f'"{name}"'.encode())
    sig = sign_digest(load_private_key(key.private_pem), sha256_hex(source))
    data = {"name": name, "stage": "noise-removal", "version": "1.0.0", "signature": sig}
    if parameters is not None:
        data["parameters"] = parameters
    with live.operator() as op:
        assert op.post("/keys", json={"name": "ci", "public_key": key.public_b64}).status_code in (201, 409)
        return op.post("/kernels", data=data, files={"file": (f"{name}.py", source, "text/x-python")})


def _choose(name: str, params: str, install: str = "") -> str:
    chosen = f'<noise-removal><kernel name="{name}">\n{params}</kernel></noise-removal>'
    return f"<xml><message>{install}{chosen}</message></xml>"


def test_declared_schema_is_kept_and_checks_messages_before_queueing(
    live: Live, key: KeyPair, schema: dict[str, Any]
) -> None:
    name = f"ro-{uuid.uuid4().hex[:6]}"
    r = _upload(live, key, name, json.dumps(schema))
    assert r.status_code == 201, r.text
    assert r.json()["parameters"]["properties"]["radius_m"]["maximum"] == 5.0
    rid, _token = live.new_robot()
    with live.operator() as op:
        assert op.get(f"/kernels/{name}/1.0.0").json()["parameters"] == schema
        digest = r.json()["sha256"]
        install = f'<kernel-install stage="noise-removal" name="{name}" version="1.0.0" sha256="{digest}"/>'
        before = op.get(f"/robots/{rid}").json()["last_seq"]
        bad = op.post(
            f"/robots/{rid}/messages",
            content=_choose(name, '<param name="radius_m" unit="m">9</param>', install),
            headers=XML,
        )
        assert bad.status_code == 422, bad.text
        detail = bad.json()["detail"]
        assert detail.startswith('line 2 <param name="radius_m">:') and "maximum of 5.0" in detail, detail
        unknown = op.post(
            f"/robots/{rid}/messages",
            content=_choose(name, '<param name="radius">1</param>', install),
            headers=XML,
        )
        assert (
            unknown.status_code == 422
            and "expected one of: min_neighbours, radius_m" in unknown.json()["detail"]
        )
        assert op.get(f"/robots/{rid}").json()["last_seq"] == before, "nothing was queued"
        good = op.post(
            f"/robots/{rid}/messages",
            content=_choose(name, '<param name="radius_m" unit="cm">6</param>', install),
            headers=XML,
        )
        assert good.status_code == 201, good.text
        # the tuning form's draft is checked the same way
        draft = {"noise_removal": [{"name": name, "version": "1.0.0", "params": {"min_neighbours": 0}}]}
        code = op.post("/control/xml", json=draft)
        assert code.status_code == 422 and "min_neighbours" in code.json()["detail"], code.text


def test_without_a_declaration_the_robot_checks_alone(live: Live, key: KeyPair) -> None:
    name = f"ro-{uuid.uuid4().hex[:6]}"
    r = _upload(live, key, name, None)
    assert r.status_code == 201 and r.json()["parameters"] is None
    draft = {"noise_removal": [{"name": name, "version": "1.0.0", "params": {"radius_m": 9.0}}]}
    with live.operator() as op:
        assert op.post("/control/xml", json=draft).status_code == 200


@pytest.mark.parametrize(
    ("parameters", "needle"),
    [
        ("{not json", "parameters: not JSON"),
        ('["a"]', "expected a JSON Schema of an object"),
        (
            '{"type": "object", "properties": {"a": {"type": "numbre"}}}',
            "not a valid JSON Schema at properties/a/type",
        ),
        ('{"type": "object", "x": "' + "y" * 70_000 + '"}', "at most 65536"),
    ],
)
def test_a_bad_declaration_is_refused_at_upload(
    live: Live, key: KeyPair, parameters: str, needle: str
) -> None:
    r = _upload(live, key, f"ro-{uuid.uuid4().hex[:6]}", parameters)
    assert r.status_code == 422, r.text
    assert needle in r.json()["detail"] and r.json().get("field") == "parameters", r.json()
