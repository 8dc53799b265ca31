"""Signed kernel artifacts through a real server: keys, upload checks, immutable versions, fetch, delete."""

from __future__ import annotations

import uuid
from typing import Any

import pytest

from shared.signing import KeyPair, generate_keypair, load_private_key, sha256_hex, sign_digest
from tests.server.live import Live

SOURCE = b'"""A test kernel."""\n\nVALUE = 1\n'


@pytest.fixture(scope="module")
def key() -> KeyPair:
    return generate_keypair()


def _register(live: Live, key: KeyPair) -> None:
    with live.operator() as op:
        r = op.post("/keys", json={"name": "ci", "public_key": key.public_b64})
        assert r.status_code in (201, 409), r.text


def _upload(live: Live, key: KeyPair, kernel: str, source: bytes = SOURCE, **fields: str) -> Any:
    sig = sign_digest(load_private_key(key.private_pem), sha256_hex(source))
    data = {"name": kernel, "stage": "noise-removal", "version": "1.0.0", "signature": sig, **fields}
    name = data["name"]
    with live.operator() as op:
        return op.post("/kernels", data=data, files={"file": (f"{name}.py", source, "text/x-python")})


def _name() -> str:
    return f"k-{uuid.uuid4().hex[:8]}"


def test_upload_fetch_and_immutability(live: Live, key: KeyPair) -> None:
    _register(live, key)
    name = _name()
    r = _upload(live, key, name)
    assert r.status_code == 201, r.text
    meta = r.json()
    assert meta["sha256"] == sha256_hex(SOURCE) and meta["key_id"] == key.key_id and meta["deleted"] is False
    assert _upload(live, key, name).status_code == 200, "the identical upload again is accepted as is"
    other = _upload(live, key, name, SOURCE + b"# changed\n")
    assert other.status_code == 409 and "immutable" in other.json()["detail"]
    _rid, token = live.new_robot()
    with live.client(token) as robot:
        art = robot.get(f"/kernels/{name}/1.0.0/artifact")
        assert art.status_code == 200 and art.content == SOURCE
        assert art.headers["etag"] == f'"{meta["sha256"]}"'
        assert art.headers["x-linemap-signature"] == meta["signature"]
        again = robot.get(f"/kernels/{name}/1.0.0/artifact", headers={"If-None-Match": art.headers["etag"]})
        assert again.status_code == 304 and again.content == b""
        assert robot.post("/kernels", data={}).status_code == 403, "robots cannot upload"
    with live.operator() as op:
        listed = op.get("/kernels", params={"name": name}).json()
        assert [k["version"] for k in listed] == ["1.0.0"]


def test_delete_keeps_the_version_taken(live: Live, key: KeyPair) -> None:
    _register(live, key)
    name = _name()
    assert _upload(live, key, name).status_code == 201
    with live.operator() as op:
        assert op.delete(f"/kernels/{name}/1.0.0").status_code == 204
        assert op.get(f"/kernels/{name}/1.0.0/artifact").status_code == 410
        assert op.get(f"/kernels/{name}/1.0.0").json()["deleted"] is True
        assert op.get("/kernels", params={"name": name}).json() == []
    assert _upload(live, key, name).status_code == 409, "a deleted version is never reused"
    assert _upload(live, key, name, version="1.0.1").status_code == 201


@pytest.mark.parametrize(
    ("fields", "source", "needle"),
    [
        ({"name": "Bad_Name"}, SOURCE, "name"),
        ({"stage": "teleportation"}, SOURCE, "stage"),
        ({"version": "1.0"}, SOURCE, "MAJOR.MINOR.PATCH"),
        ({}, b"def broken(:\n", "not valid Python: line 1"),
        ({}, b"\xff\xfe\x00", "UTF-8"),
        ({"signature": "not base64!"}, SOURCE, "base64"),
        ({"signature": "A" * 86 + "=="}, SOURCE, "does not verify"),
    ],
)
def test_bad_uploads_are_refused_with_the_reason(
    live: Live, key: KeyPair, fields: dict[str, str], source: bytes, needle: str
) -> None:
    _register(live, key)
    r = _upload(live, key, _name(), source, **fields)
    assert r.status_code == 422, r.text
    assert needle in r.json()["detail"]


def test_signature_by_an_unregistered_key_is_refused(live: Live, key: KeyPair) -> None:
    _register(live, key)
    stranger = generate_keypair()
    r = _upload(live, stranger, _name())
    assert r.status_code == 422 and "any registered key" in r.json()["detail"]


def test_keys_add_list_revoke(live: Live) -> None:
    pair = generate_keypair()
    with live.operator() as op:
        r = op.post("/keys", json={"name": "laptop", "public_key": pair.public_b64})
        assert r.status_code == 201 and r.json()["key_id"] == pair.key_id
        assert op.post("/keys", json={"name": "again", "public_key": pair.public_b64}).status_code == 409
        bad = op.post("/keys", json={"name": "bad", "public_key": "AAAA"})
        assert bad.status_code == 422 and "32 bytes" in bad.json()["detail"]
        assert op.delete(f"/keys/{pair.key_id}").status_code == 204
        keys = {k["key_id"]: k for k in op.get("/keys").json()}
        assert keys[pair.key_id]["revoked"] is True
    # A revoked key no longer signs uploads.
    r = _upload(live, pair, _name())
    assert r.status_code == 422


def test_oversize_kernel_file(live: Live, key: KeyPair) -> None:
    _register(live, key)
    big = b"X = 1\n" + b"#" * (600 * 1024)
    r = _upload(live, key, _name(), big)
    assert r.status_code == 413


def test_builtin_catalogue_lists_parameter_schemas(live: Live) -> None:
    with live.operator() as op:
        cat = op.get("/kernels/builtin").json()
    names = {k["name"] for k in cat}
    assert {"dbscan", "kmeans", "icp"} <= names


def test_stages_are_served_as_the_stage_descriptions_state_them(live: Live) -> None:
    from shared.kernels import Stage
    from shared.pipeline import PipelineConfig

    with live.operator() as op:
        stages = op.get("/kernels/stages").json()
    assert [s["stage"] for s in stages] == [str(s) for s in Stage]
    config = PipelineConfig().model_dump(mode="json")
    for s in stages:
        assert s["field"] in config  # the configuration field the dashboard reads and drafts
    by = {s["stage"]: s for s in stages}
    assert by["noise-removal"]["chain"] and not by["clustering"]["chain"]
    assert by["scan-matching"]["optional"] and not by["segmentation"]["optional"]
    assert by["straight-line"]["element"] == "straight-line-method"
    with live.client() as anon:
        assert anon.get("/kernels/stages").status_code == 401
