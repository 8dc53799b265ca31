"""Kernel uploads through a real server: pathological source never answers 5xx, and a version number has
one spelling (leading zeros refused, a stored re-spelling of the same number is a conflict)."""

from __future__ import annotations

import uuid
from collections.abc import Callable

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from server.models import KernelArtifact
from shared.signing import KeyPair, generate_keypair, load_private_key, sha256_hex, sign_digest
from tests.server.live import Live

GOOD = b'"""A test kernel."""\n\nVALUE = 1\n'


@pytest.fixture(scope="module")
def key() -> KeyPair:
    return generate_keypair()


def _upload(live: Live, key: KeyPair, name: str, source: bytes, version: str = "1.0.0") -> tuple[int, str]:
    with live.operator() as op:
        op.post("/keys", json={"name": "ci", "public_key": key.public_b64})
        sig = sign_digest(load_private_key(key.private_pem), sha256_hex(source))
        data = {"name": name, "stage": "noise-removal", "version": version, "signature": sig}
        r = op.post("/kernels", data=data, files={"file": (f"{name}.py", source, "text/x-python")})
        return r.status_code, r.text


def _name() -> str:
    return f"k-{uuid.uuid4().hex[:8]}"


#: Small sources that made CPython's parser raise RecursionError / MemoryError (or take seconds).
PATHOLOGICAL: dict[str, Callable[[int], str]] = {
    "parens": lambda n: "x = " + "(" * n + "1" + ")" * n,
    "sum": lambda n: "x = " + "+".join(["1"] * n),
    "unary": lambda n: "x = " + "-" * n + "1",
    "not": lambda n: "x = " + "not " * n + "1",
    "lambda": lambda n: "x = " + "lambda: " * n + "1",
    "ifexpr": lambda n: "x = " + "1 if 1 else " * n + "1",
    "calls": lambda n: "x = f" + "()" * n,
    "attributes": lambda n: "x = a" + ".b" * n,
    "subscripts": lambda n: "x = a" + "[0]" * n,
    "power": lambda n: "x = " + "**".join(["2"] * n),
    "lists": lambda n: "x = " + "[" * n + "]" * n,
    "indent": lambda n: (
        "".join(" " * i + "if 1:\n" for i in range(min(n, 600))) + " " * min(n, 600) + "pass\n"
    ),
    "string-times": lambda n: "x = 'a' * 10 ** 10\ny = b'x' * 10 ** 12\n" * n,
    "big-int": lambda n: "x = " + "9" * n,
}


@pytest.mark.parametrize("shape", sorted(PATHOLOGICAL))
@pytest.mark.parametrize("n", [1000, 60_000])
def test_pathological_source_is_refused_with_422_never_5xx(
    live: Live, key: KeyPair, shape: str, n: int
) -> None:
    source = PATHOLOGICAL[shape](n).encode()[: 200 * 1024]  # under the request limit
    status, text = _upload(live, key, _name(), source)
    assert status in (201, 422), text
    if status == 422:
        assert "file:" in text and ("expected" in text or "not valid Python" in text), text
    with live.operator() as op:
        assert op.get("/kernels").status_code == 200  # the server still answers


def test_deep_sum_names_the_reason(live: Live, key: KeyPair) -> None:
    status, text = _upload(live, key, _name(), PATHOLOGICAL["sum"](100_000).encode())
    assert status == 422 and "too complex to parse" in text and "nested at most" in text, text
    status, text = _upload(live, key, _name(), PATHOLOGICAL["sum"](500).encode())
    assert status == 422 and "nested too deeply" in text, text
    assert _upload(live, key, _name(), GOOD)[0] == 201


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    st.one_of(
        st.binary(max_size=300),
        st.text(alphabet=st.sampled_from("()[]{}+-*~ notlambda:if else1x=\n\t,.'\"\\#@"), max_size=400),
    ),
    st.sampled_from(sorted(PATHOLOGICAL)),
    st.integers(min_value=1, max_value=30_000),
)
def test_no_upload_source_answers_5xx(
    live: Live, key: KeyPair, noise: bytes | str, shape: str, n: int
) -> None:
    head = noise if isinstance(noise, bytes) else noise.encode()
    source = (head + PATHOLOGICAL[shape](n).encode())[: 200 * 1024]  # under the request limit (413)
    status, text = _upload(live, key, _name(), source)
    assert status in (201, 422), text


@pytest.mark.parametrize(
    "version", ["01.0.0", "1.00.0", "1.0.00", "00.0.0", "1.0.0\n", "\u0661.0.0", "+1.0.0"]
)
def test_versions_with_another_spelling_are_refused(live: Live, key: KeyPair, version: str) -> None:
    status, text = _upload(live, key, _name(), GOOD, version=version)
    assert status == 422 and "MAJOR.MINOR.PATCH" in text and "leading" in text, text


def test_a_stored_respelling_of_the_same_number_is_a_conflict(live: Live, key: KeyPair) -> None:
    name = _name()
    with live.state.db.session() as s:  # a row stored before the canonical spelling was enforced
        s.add(
            KernelArtifact(
                name=name,
                version="01.0.0",
                stage="noise-removal",
                sha256=sha256_hex(GOOD),
                size_bytes=len(GOOD),
                source=GOOD,
                signature="x",
                key_id="legacy",
                uploaded_by="operator:legacy",
            )
        )
    status, text = _upload(live, key, name, GOOD + b"# other code\n")
    assert status == 409 and "01.0.0" in text and "immutable" in text, text
    assert _upload(live, key, name, GOOD, version="1.0.1")[0] == 201
