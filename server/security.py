"""Tokens: made with :mod:`secrets`, shown once, stored as SHA-256 hashes (they carry 256 random bits, so
a fast hash is enough; a stolen database yields no usable token)."""

from __future__ import annotations

import hashlib
import secrets

__all__ = ["OPERATOR_PREFIX", "ROBOT_PREFIX", "SESSION_PREFIX", "hash_token", "new_token"]

OPERATOR_PREFIX = "lmo_"
ROBOT_PREFIX = "lmr_"
SESSION_PREFIX = "lms_"


def new_token(prefix: str) -> str:
    """A new random token: ``prefix`` then 43 URL-safe characters (256 bits)."""
    return prefix + secrets.token_urlsafe(32)


def hash_token(token: str) -> str:
    """Hex SHA-256 of the token: what the database stores and looks tokens up by."""
    return hashlib.sha256(token.encode("utf-8", "surrogatepass")).hexdigest()
