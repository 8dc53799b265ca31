"""shared.protocol: each message survives model -> JSON -> model unchanged, the JSON keeps the field names
older robots and servers use, and each pattern is written once (the XSD repeats them: compared here)."""

from __future__ import annotations

import json
import re
import uuid
from datetime import UTC, datetime

import pytest
from hypothesis import given
from hypothesis import strategies as st
from pydantic import BaseModel, ValidationError

from shared.control import xsd_text
from shared.protocol import (
    KERNEL_NAME_PATTERN,
    KERNEL_NAME_RE,
    MAP_SESSION_RE,
    SHA256_PATTERN,
    SHA256_RE,
    VERSION_PATTERN,
    VERSION_RE,
    KernelMeta,
    MapDelta,
    MapSnapshot,
    MapUpload,
    MessageAck,
    RobotKernel,
    RobotStatus,
)

_KERNEL = RobotKernel(stage="noise-removal", name="dbscan", version="1.0.0", state="active", sha256="ab" * 32)
_STATUS = RobotStatus(
    mode="online",
    active_kernels={"noise-removal": "dbscan@1.0.0"},
    step_ms=3.5,
    last_error=None,
    config={"mode": "online"},
    kernels=[_KERNEL],
)
_DELTA = MapDelta(
    version=7,
    base_version=5,
    stamp_s=0.7,
    wall_time_s=1.8e9,
    segments=[[3.0, 0.0, 0.0, 1.0, 0.5]],
    removed=[1, 2],
    centroids=[[0.5, 0.25]],
    pose=[1.0, 2.0, 0.5],
    trajectory=[[0.6, 1.0, 2.0, 0.4], [0.7, 1.0, 2.0, 0.5]],
    status=_STATUS,
)
_SNAPSHOT = MapSnapshot(
    version=7,
    stamp_s=0.7,
    segments=[[3.0, 0.0, 0.0, 1.0, 0.5], [4.0, 1.0, 0.5, 1.0, 2.0]],
    centroids=[[0.5, 0.25]],
    pose=[1.0, 2.0, 0.5],
    trajectory=[[0.7, 1.0, 2.0, 0.5]],
)
_ACKS = [
    MessageAck(outcome="applied"),
    MessageAck(outcome="rejected", reason="unknown kernel"),
    MessageAck(outcome="rolled-back", reason="kernel hung"),
]
_META = KernelMeta(
    name="my-dbscan",
    version="1.2.0",
    stage="noise-removal",
    sha256="cd" * 32,
    size_bytes=1234,
    signature="c2ln",
    key_id="0123456789abcdef",
    uploaded_at=datetime(2026, 12, 5, 12, 0, tzinfo=UTC),
    uploaded_by="operator",
    deleted=False,
)


@pytest.mark.parametrize(
    "message", [_KERNEL, _STATUS, _DELTA, _SNAPSHOT, *_ACKS, _META], ids=lambda m: type(m).__name__
)
def test_model_json_model_roundtrip(message: BaseModel) -> None:
    text = message.model_dump_json()
    again = type(message).model_validate_json(text)
    assert again == message
    assert again.model_dump_json() == text
    # the robot sends model_dump(mode="json") through json.dumps: the same document
    assert json.loads(json.dumps(message.model_dump(mode="json"))) == json.loads(text)


def test_deltas_and_snapshots_are_map_uploads_with_the_legacy_field_names() -> None:
    legacy = {
        "version", "base_version", "stamp_s", "segments", "removed", "centroids", "pose", "trajectory",
        "status", "wall_time_s",
    }  # fmt: skip
    for body in (_DELTA, _SNAPSHOT):
        dumped = body.model_dump(mode="json")
        assert set(dumped) == legacy
        assert MapUpload.model_validate(dumped).model_dump() == body.model_dump()
    assert _SNAPSHOT.model_dump(mode="json")["base_version"] is None
    assert set(_STATUS.model_dump(mode="json")) == {
        "mode", "active_kernels", "step_ms", "last_error", "config", "kernels",
    }  # fmt: skip
    assert set(_ACKS[1].model_dump(mode="json")) == {"outcome", "reason"}


def test_a_delta_needs_its_base_and_a_snapshot_removes_nothing() -> None:
    with pytest.raises(ValidationError):
        MapDelta.model_validate({"version": 3})
    with pytest.raises(ValidationError):
        MapDelta(version=3, base_version=3)
    with pytest.raises(ValidationError):
        MapSnapshot.model_validate({"version": 3, "removed": [1]})
    with pytest.raises(ValidationError):
        MapSnapshot.model_validate({"version": 3, "base_version": 2})
    with pytest.raises(ValidationError, match="needs a reason"):
        MessageAck(outcome="rejected", reason="  ")


def _xsd_pattern(simple_type: str) -> str:
    found = re.search(
        rf'<xs:simpleType name="{simple_type}">.*?<xs:pattern value="([^"]+)"', xsd_text(), re.S
    )
    assert found is not None, simple_type
    return found.group(1)


@pytest.mark.parametrize(
    ("simple_type", "pattern"),
    [("KernelName", KERNEL_NAME_PATTERN), ("Version", VERSION_PATTERN), ("Sha256", SHA256_PATTERN)],
)
def test_the_xsd_spells_each_pattern_as_the_protocol_does(simple_type: str, pattern: str) -> None:
    assert _xsd_pattern(simple_type) == pattern


@pytest.mark.parametrize(
    ("regex", "good", "bad"),
    [
        (KERNEL_NAME_RE, ["dbscan", "my-dbscan2", "a-1-b"], ["Dbscan", "dbscan_x", "-a", "a--b", "a\n"]),
        (VERSION_RE, ["0.0.0", "1.20.300"], ["01.0.0", "1.0", "1.0.0\n", "1.0.0.0"]),
        (SHA256_RE, ["ab" * 32, "AB" * 32], ["ab" * 31, "zz" * 32, "ab" * 32 + "\n"]),
    ],
)
def test_patterns_take_whole_names_only(regex: re.Pattern[str], good: list[str], bad: list[str]) -> None:
    assert all(regex.fullmatch(text) for text in good)
    assert not any(regex.fullmatch(text) for text in bad)


def test_every_pattern_is_written_once() -> None:
    """The kernel-name and SHA-256 patterns appear in the protocol module and nowhere else in the code
    (the XSD's copies are compared above)."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    spellings = [KERNEL_NAME_PATTERN, SHA256_PATTERN, "(0|[1-9][0-9]"]
    for package in ("shared", "server", "robot_agent"):
        for path in (root / package).rglob("*.py"):
            if path.parts[-2:] == ("protocol", "patterns.py"):
                continue
            text = path.read_text(encoding="utf-8")
            for spelling in spellings:
                assert spelling not in text, f"{path.relative_to(root)} spells {spelling!r} again"


@given(st.uuids())
def test_a_map_session_is_a_lower_case_uuid(value: uuid.UUID) -> None:
    text = str(value)
    assert MAP_SESSION_RE.fullmatch(text)
    assert MapSnapshot(version=1, map_session=text).model_dump(mode="json")["map_session"] == text
    for bad in (text.upper(), text.replace("-", ""), text + "\n", "{" + text + "}", text[:-1]):
        if bad == text:
            continue
        assert not MAP_SESSION_RE.fullmatch(bad)
        with pytest.raises(ValidationError, match="map_session"):
            MapDelta.model_validate({"version": 2, "base_version": 1, "map_session": bad})


def test_an_upload_with_a_session_carries_it_and_one_without_keeps_the_legacy_fields() -> None:
    session = "0b7f4a8e-3c1d-4e5f-9a6b-7c8d9e0f1a2b"
    body = MapSnapshot(version=4, map_session=session, map_session_reason="new Robot DB")
    dumped = body.model_dump(mode="json")
    assert dumped["map_session"] == session and dumped["map_session_reason"] == "new Robot DB"
    assert MapUpload.model_validate(dumped).map_session == session
    assert "map_session" not in MapSnapshot(version=4).model_dump(mode="json")
    with pytest.raises(ValidationError, match="map_session_reason"):
        MapSnapshot(version=4, map_session=session, map_session_reason="x" * 301)


@pytest.mark.parametrize("text", ["NaN", "Infinity", "-Infinity"])
def test_a_status_config_with_a_non_finite_number_is_refused_naming_where(text: str) -> None:
    """JSON text may spell NaN and infinities; JSON itself and the server's JSON columns have none, so a
    configuration holding one is refused (on PostgreSQL it failed the write; encoded again it became null)."""
    raw = '{"config": {"noise": {"eps_m": 0.05, "w": [1.0, NUMBER]}}}'.replace("NUMBER", text)
    with pytest.raises(ValidationError, match=r"config\.noise\.w\[1\].*finite"):
        RobotStatus.model_validate_json(raw)
    assert RobotStatus.model_validate_json('{"config": {"noise": {"w": [1.0, 2]}}}').config == {
        "noise": {"w": [1.0, 2]}
    }
    # the robot's own status is built from Python values and written by pydantic, which writes null
    mine = RobotStatus.model_validate(
        {"config": {"noise": {"w": [1.0, float(text.replace("Infinity", "inf"))]}}}
    )
    assert json.loads(mine.model_dump_json())["config"] == {"noise": {"w": [1.0, None]}}
