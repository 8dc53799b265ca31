"""The first check of a downloaded kernel, on its artifact: The SHA-256 of the source matches the message's,
and an Ed25519 signature by a key the robot trusts covers it (unsigned code only with the
``--allow-unsigned`` development flag). Refusals raise :class:`~robot_agent.errors.KernelRejected` with the
reason the server is told. O(source size).
"""

from __future__ import annotations

from collections.abc import Sequence

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

from robot_agent.errors import KernelRejected
from shared.signing import SignatureError, key_id, sha256_hex, verify_digest

__all__ = ["verify_artifact"]

_UNSIGNED = "unsigned kernel refused; run the agent with --allow-unsigned for development"


def verify_artifact(
    source: bytes,
    sha256: str,
    signature: str | None,
    trusted: Sequence[Ed25519PublicKey],
    allow_unsigned: bool = False,
) -> str | None:
    """Check a kernel artifact's digest and signature; return the id of the key that signed it.

    ``sha256`` is the hex digest the control message names, ``signature`` the base64 Ed25519 signature over
    it (:func:`shared.signing.sign_digest`), ``trusted`` the public keys this robot accepts. Returns the
    signing key's id, or ``None`` for unsigned code accepted because ``allow_unsigned`` is set (development
    only). A signature that is present is always checked, even with ``allow_unsigned``.

    Raises :class:`KernelRejected`: "sha256 mismatch: expected X, got Y"; "unsigned kernel refused; ...";
    no trusted keys configured; a signature that is malformed or verifies with none of the keys.
    O(len(source)) for the hash, then ~0.1 ms per trusted key.
    """
    got = sha256_hex(source)
    if got != sha256.strip().lower():
        raise KernelRejected(f"sha256 mismatch: expected {sha256}, got {got}")
    if not signature:
        if allow_unsigned:
            return None
        raise KernelRejected(_UNSIGNED)
    if not trusted:
        raise KernelRejected(
            "signed kernel refused: this robot trusts no signing key; add the operator's public key"
            " (linemap keys generate prints it) to the agent's trusted keys"
        )
    failures: list[str] = []
    for key in trusted:
        try:
            verify_digest(key, got, signature)
        except SignatureError as exc:
            failures.append(str(exc))
            continue
        return key_id(key)
    if any(not f.startswith("signature does not verify") for f in failures):
        malformed = next(f for f in failures if not f.startswith("signature does not verify"))
        raise KernelRejected(f"bad signature: {malformed}")
    ids = ", ".join(key_id(k) for k in trusted)
    raise KernelRejected(f"bad signature: it verifies with none of the trusted keys ({ids})")
