"""The agent <-> kernel worker message format (robot_agent/kernels/wire.py): what a worker sends is untrusted,
so decoding anything either gives the values back or raises WireError, never another exception."""

from __future__ import annotations

import contextlib
import json
import socket
import struct
import time
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_agent.kernels import wire
from shared.kernels import NoiseResult
from shared.types import Pose2D

json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4),
    max_leaves=20,
)


def _roundtrip(value: Any) -> Any:
    a, b = socket.socketpair()
    with a, b:
        wire.send(a, value, 5.0)
        return wire.receive(b, time.monotonic() + 5.0)


def test_arrays_and_results_cross_intact() -> None:
    pts = np.random.default_rng(0).normal(size=(50, 2))
    result = NoiseResult(np.ones(50, dtype=bool), pts, np.zeros(50, dtype=np.intp))
    got = _roundtrip({"ok": [result, Pose2D(1.0, 2.0, 0.5), pts[:0]]})["ok"]
    assert isinstance(got[0], NoiseResult) and np.array_equal(got[0].points, pts)
    assert got[0].keep.dtype == bool and got[1] == Pose2D(1.0, 2.0, 0.5) and got[2].shape == (0, 2)


def test_objects_that_are_not_data_never_cross() -> None:
    with pytest.raises(wire.WireError, match="cannot cross"):
        _roundtrip({"ok": object()})
    with pytest.raises(wire.WireError, match="numeric or boolean"):
        _roundtrip({"ok": np.array(["a"], dtype=object)})


@settings(max_examples=200, deadline=None)
@given(json_values)
def test_json_values_round_trip(value: Any) -> None:
    assert _roundtrip(value) == value


@settings(max_examples=300, deadline=None)
@given(json_values, st.lists(st.binary(max_size=64), max_size=4))
def test_decoding_garbage_gives_a_wire_error_or_a_value(tree: Any, frames: list[bytes]) -> None:
    for value in (tree, {"__nd__": tree, "dtype": tree, "shape": tree}, {"__dc__": "Segments", "f": tree}):
        with contextlib.suppress(wire.WireError):  # anything else fails the test
            wire.decode(value, frames)


@pytest.mark.parametrize(
    "header",
    [
        {"__nd__": 0, "dtype": "<f8", "shape": [2**62, 2**62]},  # would wrap around in int64
        {"__nd__": 0, "dtype": "|O", "shape": [1]},
        {"__nd__": 0, "dtype": "<f8", "shape": [-1]},
        {"__nd__": 5, "dtype": "<f8", "shape": [1]},
        {"__dc__": "Popen", "f": {}},
        {"__dc__": "Pose2D", "f": {"x_m": "nan-ish"}},
        {"__dc__": "Pose2D", "f": {"evil": 1}},
    ],
)
def test_hostile_descriptors_are_refused(header: dict[str, Any]) -> None:
    with pytest.raises(wire.WireError):
        wire.decode(header, [b"\0" * 8])


def test_a_message_over_the_size_limit_or_too_deep_is_refused() -> None:
    a, b = socket.socketpair()
    with a, b:
        head = json.dumps({"n": 2, "v": None}).encode()
        a.sendall(struct.pack("!I", len(head)) + head + struct.pack("!Q", wire.MAX_MESSAGE_BYTES))
        with pytest.raises(wire.WireError, match="more than"):
            wire.receive(b, time.monotonic() + 5)
    a, b = socket.socketpair()
    with a, b:
        head = ('{"n": 0, "v": ' + "[" * 100_000 + "]" * 100_000 + "}").encode()
        a.sendall(struct.pack("!I", len(head)) + head)
        with pytest.raises(wire.WireError):
            wire.receive(b, time.monotonic() + 5)


def test_a_slow_drip_answer_times_out() -> None:
    a, b = socket.socketpair()
    with a, b:
        a.sendall(struct.pack("!I", 100) + b"{")  # a header that never completes
        with pytest.raises(TimeoutError):
            wire.receive(b, time.monotonic() + 0.2)
