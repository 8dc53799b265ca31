"""Ed25519 signatures over kernel artifacts (docs/design.md §7, §9): the operator signs, server and robot
verify.

A signature covers the artifact's SHA-256 digest (the 32 raw bytes, not the hex text), so a signature
can be checked against the digest a control message names before the artifact is even downloaded.
Keys travel as base64 of the 32 raw public-key bytes (what ``linemap keys generate`` prints) or as PEM;
a key's id is the first 16 hex digits of the SHA-256 of its raw bytes.

Cost: signing and verifying are O(1) (~50-100 µs each with ``cryptography``), hashing O(n) in bytes.
"""

from __future__ import annotations

import base64
import binascii
import hashlib
from dataclasses import dataclass

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey, Ed25519PublicKey

from shared.errors import LinemapError

__all__ = [
    "KeyPair",
    "SignatureError",
    "generate_keypair",
    "key_id",
    "load_private_key",
    "load_public_key",
    "public_key_text",
    "sha256_hex",
    "sign_digest",
    "verify_digest",
]


class SignatureError(LinemapError, ValueError):
    """A key or signature is malformed, or a signature does not verify."""


@dataclass(frozen=True, slots=True)
class KeyPair:
    """A new signing key: ``private_pem`` (PKCS#8, unencrypted) and ``public_b64`` (raw 32 bytes)."""

    private_pem: str
    public_b64: str

    @property
    def key_id(self) -> str:
        return key_id(load_public_key(self.public_b64))


def sha256_hex(data: bytes) -> str:
    """Lower-case hex SHA-256 of ``data`` (64 digits)."""
    return hashlib.sha256(data).hexdigest()


def generate_keypair() -> KeyPair:
    """A fresh Ed25519 key pair."""
    private = Ed25519PrivateKey.generate()
    pem = private.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
    ).decode("ascii")
    return KeyPair(pem, public_key_text(private.public_key()))


def public_key_text(key: Ed25519PublicKey) -> str:
    """Base64 of the key's 32 raw bytes."""
    raw = key.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)
    return base64.b64encode(raw).decode("ascii")


def key_id(key: Ed25519PublicKey) -> str:
    """First 16 hex digits of the SHA-256 of the raw public key."""
    raw = key.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw)
    return hashlib.sha256(raw).hexdigest()[:16]


def load_public_key(text: str | bytes) -> Ed25519PublicKey:
    """An Ed25519 public key from base64 of its 32 raw bytes or from PEM (SubjectPublicKeyInfo)."""
    data = text.encode("ascii", "replace") if isinstance(text, str) else text
    data = data.strip()
    if data.startswith(b"-----BEGIN"):
        try:
            key = serialization.load_pem_public_key(data)
        except ValueError as exc:
            raise SignatureError(f"public key: PEM could not be read ({exc})") from None
        if not isinstance(key, Ed25519PublicKey):
            raise SignatureError(f"public key: expected an Ed25519 key, got {type(key).__name__}")
        return key
    raw = _b64(data, "public key")
    if len(raw) != 32:
        raise SignatureError(f"public key: expected 32 bytes of Ed25519 key in base64, got {len(raw)} bytes")
    return Ed25519PublicKey.from_public_bytes(raw)


def load_private_key(pem: str | bytes) -> Ed25519PrivateKey:
    """An Ed25519 private key from unencrypted PEM (what :func:`generate_keypair` writes)."""
    data = pem.encode("ascii", "replace") if isinstance(pem, str) else pem
    try:
        key = serialization.load_pem_private_key(data.strip(), password=None)
    except (ValueError, TypeError) as exc:
        raise SignatureError(f"private key: expected an unencrypted PEM Ed25519 key ({exc})") from None
    if not isinstance(key, Ed25519PrivateKey):
        raise SignatureError(f"private key: expected an Ed25519 key, got {type(key).__name__}")
    return key


def sign_digest(private: Ed25519PrivateKey, sha256: str) -> str:
    """Base64 Ed25519 signature over the 32 raw bytes of the hex digest ``sha256``."""
    return base64.b64encode(private.sign(_digest_bytes(sha256))).decode("ascii")


def verify_digest(public: Ed25519PublicKey, sha256: str, signature_b64: str) -> None:
    """Raise :class:`SignatureError` unless ``signature_b64`` signs ``sha256`` with ``public``."""
    sig = _b64(signature_b64.encode("ascii", "replace"), "signature")
    if len(sig) != 64:
        raise SignatureError(f"signature: expected 64 bytes of Ed25519 signature in base64, got {len(sig)}")
    try:
        public.verify(sig, _digest_bytes(sha256))
    except InvalidSignature:
        raise SignatureError(
            f"signature does not verify for sha256 {sha256} with key {key_id(public)}"
        ) from None


def _digest_bytes(sha256: str) -> bytes:
    if len(sha256) != 64:
        raise SignatureError(f"sha256: expected 64 hex digits, got {len(sha256)} characters")
    try:
        return bytes.fromhex(sha256)
    except ValueError:
        raise SignatureError(f"sha256: expected 64 hex digits, got {sha256[:70]!r}") from None


def _b64(data: bytes, what: str) -> bytes:
    try:
        return base64.b64decode(data, validate=True)
    except (binascii.Error, ValueError):
        raise SignatureError(f"{what}: not valid base64") from None
