"""server.jsontext against the reference it replaces on the upload path, ``json.dumps``: the same JSON
values for any plain data, and doubles read back exactly (the delta log, undo records and PostgreSQL's row
parameters are parsed again later)."""

from __future__ import annotations

import json
import math
from typing import Any

from hypothesis import given
from hypothesis import strategies as st

from server.jsontext import dumps

_leaves = (
    st.none()
    | st.booleans()
    | st.integers(min_value=-(2**63), max_value=2**63 - 1)
    | st.floats(allow_nan=False, allow_infinity=False)
    | st.text(max_size=20)
)
_plain = st.recursive(
    _leaves,
    lambda inner: st.lists(inner, max_size=6) | st.dictionaries(st.text(max_size=8), inner, max_size=6),
    max_leaves=40,
)


@given(_plain)
def test_the_same_json_values_as_json_dumps(obj: Any) -> None:
    assert json.loads(dumps(obj)) == json.loads(json.dumps(obj))


@given(st.lists(st.floats(allow_nan=False, allow_infinity=False), max_size=50))
def test_doubles_read_back_exactly(values: list[float]) -> None:
    back = json.loads(dumps(values))
    pairs = zip(back, values, strict=True)
    assert all(a == b and math.copysign(1, a) == math.copysign(1, b) for a, b in pairs)


def test_compact_and_byte_identical_for_an_upload_event_without_exponents() -> None:
    event = {
        "kind": "delta",
        "robot_id": 3,
        "segments": [[1.0, -2.5, 3.25, 0.001, 12.600000000000001]],
        "removed": [4, 5],
        "pose": [0.0, -0.0, 3.141592653589793],
        "keyframes": None,
        "map_session": "00000000-0000-4000-8000-000000000001",
    }
    assert dumps(event) == json.dumps(event, separators=(",", ":"))
    assert dumps([1e-7]) == "[1e-7]"  # where the spelling differs from json.dumps' 1e-07
