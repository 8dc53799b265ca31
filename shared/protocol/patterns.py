"""The one spelling of each name robot and server exchange: kernel names, kernel versions, SHA-256 digests,
map session ids.

Each pattern is written once, here, unanchored (as XSD patterns are: ``shared/control/control.xsd`` repeats
them and a test keeps the two equal). In Python use the compiled ``*_RE`` with ``fullmatch`` (``match``
with ``$`` would accept a trailing newline); in a pydantic ``Field(pattern=...)`` use :func:`anchored`
(pydantic-core's Rust regex searches, and its ``$`` is the end of the text only). A version is
``MAJOR.MINOR.PATCH`` without leading zeros, so each number triple has exactly one spelling (see
:mod:`shared.kernels.versions`, which compares them). Matching is O(len(text)).
"""

from __future__ import annotations

import re

__all__ = [
    "KERNEL_NAME_MAX_LENGTH",
    "KERNEL_NAME_PATTERN",
    "KERNEL_NAME_RE",
    "MAP_SESSION_PATTERN",
    "MAP_SESSION_RE",
    "MAX_COMPONENT_DIGITS",
    "SHA256_PATTERN",
    "SHA256_RE",
    "VERSION_PATTERN",
    "VERSION_RE",
    "anchored",
]

#: A kernel name: lower-case ASCII words of letters and digits joined by ``-`` (``dbscan``, ``my-dbscan2``).
KERNEL_NAME_PATTERN = r"[a-z][a-z0-9]*(-[a-z0-9]+)*"
#: Longest kernel name the server stores (characters).
KERNEL_NAME_MAX_LENGTH = 64
KERNEL_NAME_RE = re.compile(KERNEL_NAME_PATTERN)

#: Digits a version component may have (999999 is the largest component).
MAX_COMPONENT_DIGITS = 6
_PART = f"(0|[1-9][0-9]{{0,{MAX_COMPONENT_DIGITS - 1}}})"
#: The canonical spelling of a version, ``MAJOR.MINOR.PATCH``.
VERSION_PATTERN = rf"{_PART}\.{_PART}\.{_PART}"
VERSION_RE = re.compile(VERSION_PATTERN)

#: A SHA-256 digest in hexadecimal (either case on input; the server and the robot store lower case).
SHA256_PATTERN = r"[0-9a-fA-F]{64}"
SHA256_RE = re.compile(SHA256_PATTERN)


#: A map session id (docs/reliability/identity.md): a UUID in its canonical lower-case
#: 8-4-4-4-12 spelling, created by the robot when its Robot DB starts a new map.
MAP_SESSION_PATTERN = r"[0-9a-f]{8}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{12}"
MAP_SESSION_RE = re.compile(MAP_SESSION_PATTERN)


def anchored(pattern: str) -> str:
    """``pattern`` anchored at both ends, for pydantic's ``Field(pattern=...)``."""
    return f"^{pattern}$"
