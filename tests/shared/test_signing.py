"""Ed25519 signatures over SHA-256 digests: round trip, tampering, wrong keys, malformed input."""

from __future__ import annotations

import base64

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.signing import (
    SignatureError,
    generate_keypair,
    load_private_key,
    load_public_key,
    sha256_hex,
    sign_digest,
    verify_digest,
)

PAIR = generate_keypair()
PRIVATE = load_private_key(PAIR.private_pem)
PUBLIC = load_public_key(PAIR.public_b64)


@settings(max_examples=50, deadline=None)
@given(st.binary(max_size=2048), st.binary(min_size=1, max_size=64))
def test_sign_verify_round_trip_and_any_change_breaks_it(data: bytes, extra: bytes) -> None:
    digest = sha256_hex(data)
    sig = sign_digest(PRIVATE, digest)
    verify_digest(PUBLIC, digest, sig)
    with pytest.raises(SignatureError, match="does not verify"):
        verify_digest(PUBLIC, sha256_hex(data + extra), sig)


def test_wrong_key_and_pem_keys() -> None:
    digest = sha256_hex(b"kernel")
    sig = sign_digest(PRIVATE, digest)
    other = generate_keypair()
    with pytest.raises(SignatureError, match=other.key_id):
        verify_digest(load_public_key(other.public_b64), digest, sig)
    from cryptography.hazmat.primitives import serialization

    pem = PUBLIC.public_bytes(serialization.Encoding.PEM, serialization.PublicFormat.SubjectPublicKeyInfo)
    verify_digest(load_public_key(pem.decode()), digest, sig)


@pytest.mark.parametrize(
    ("call", "needle"),
    [
        (lambda: load_public_key("AAAA"), "32 bytes"),
        (lambda: load_public_key("@@@"), "base64"),
        (lambda: load_public_key("-----BEGIN PUBLIC KEY-----\nxx\n-----END PUBLIC KEY-----"), "PEM"),
        (lambda: load_private_key("not a key"), "PEM"),
        (lambda: verify_digest(PUBLIC, "ab", base64.b64encode(bytes(64)).decode()), "64 hex digits"),
        (lambda: verify_digest(PUBLIC, "z" * 64, base64.b64encode(bytes(64)).decode()), "hex"),
        (lambda: verify_digest(PUBLIC, "a" * 64, base64.b64encode(bytes(10)).decode()), "64 bytes"),
    ],
)
def test_malformed_input_names_the_problem(call: object, needle: str) -> None:
    with pytest.raises(SignatureError, match=needle):
        call()  # type: ignore[operator]
