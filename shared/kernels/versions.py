"""The one spelling of a kernel version, and how versions compare (docs/design.md §9: versions are immutable).

A version is ``MAJOR.MINOR.PATCH``: three decimal numbers of ASCII digits, each ``0`` or a number without a
leading zero, at most :data:`MAX_COMPONENT_DIGITS` digits (so ``1.0.0`` and ``10.20.300``, never ``01.0.0``,
``1.00.0``, ``+1.0.0``, ``1.0.0\\n`` or non-ASCII digits such as ``١.0.0``). Each spelling therefore names
exactly one number triple and each triple has exactly one spelling: two versions are the same version if
and only if their strings are equal, so "immutable versions" cannot be sidestepped by re-spelling one.

Every place that checks a version uses :data:`VERSION_PATTERN`, defined once in
:mod:`shared.protocol.patterns` and re-exported here (the server's upload form and its JSON
control drafts, the control XML parser and its XSD, whose pattern a test compares with this one) and every
comparison uses :func:`parse_version` (the registry, the robot's anti-rollback floors). All functions are
O(len(text)).
"""

from __future__ import annotations

import re

from shared.protocol.patterns import MAX_COMPONENT_DIGITS, VERSION_PATTERN, VERSION_RE

__all__ = [
    "MAX_COMPONENT_DIGITS",
    "VERSION_PATTERN",
    "VERSION_RE",
    "is_version",
    "legacy_version_key",
    "parse_version",
]

_LEGACY = re.compile(r"([0-9]+)\.([0-9]+)\.([0-9]+)")


def parse_version(version: str) -> tuple[int, int, int]:
    """``"1.2.3"`` -> ``(1, 2, 3)``; raises ``ValueError`` naming the bad version and the expected form."""
    match = VERSION_RE.fullmatch(version) if isinstance(version, str) else None
    if match is None:
        shown = version[:40] if isinstance(version, str) else version
        raise ValueError(
            f"version {shown!r} is invalid: expected MAJOR.MINOR.PATCH, three numbers without leading"
            f" zeros of at most {MAX_COMPONENT_DIGITS} digits each, e.g. '1.0.0' or '2.10.3'"
        )
    major, minor, patch = (int(g) for g in match.groups())
    return major, minor, patch


def is_version(text: object) -> bool:
    """Whether ``text`` is a version in the canonical spelling."""
    return isinstance(text, str) and VERSION_RE.fullmatch(text) is not None


def legacy_version_key(text: str) -> tuple[int, int, int] | None:
    """The number triple of a version stored before the canonical spelling was enforced (ASCII digits,
    leading zeros allowed, e.g. ``"01.0.0"`` -> ``(1, 0, 0)``), or None if it is not even that. Used only
    to compare stored rows with a new version (one triple, one version)."""
    match = _LEGACY.fullmatch(text) if isinstance(text, str) else None
    if match is None:
        return None
    major, minor, patch = (int(g) for g in match.groups())
    return major, minor, patch
