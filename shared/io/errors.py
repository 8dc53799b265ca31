"""Errors of the log readers and writers (:mod:`shared.io`).

Every message names the file, the line (1-based, counted in the decompressed text), the record type, the
field and what was expected, e.g. ``aces.clf line 1234: FLASER declares 180 ranges but has 179 values``.
"""

from __future__ import annotations

from pathlib import Path

from shared.errors import LinemapError

__all__ = [
    "LogError",
    "LogFormatError",
    "LogNotFoundError",
    "NoScansError",
    "RosbagError",
    "RosbagMessageError",
    "RosbagTopicError",
    "UnknownLogFormatError",
]


class LogError(LinemapError):
    """A log file cannot be opened, read or written."""


class LogFormatError(LogError, ValueError):
    """A record of a log is malformed: ``path``, 1-based ``line_no`` and ``reason`` say where and why."""

    def __init__(self, path: Path | str, line_no: int, reason: str) -> None:
        self.path = Path(path)
        self.line_no = int(line_no)
        self.reason = reason
        super().__init__(f"{self.path.name} line {self.line_no}: {reason}")

    def __reduce__(self) -> tuple[type[LogFormatError], tuple[Path, int, str]]:
        return (type(self), (self.path, self.line_no, self.reason))


class UnknownLogFormatError(LogError, ValueError):
    """The log's format is not one the readers know (by name, suffix or content)."""


class LogNotFoundError(LogError, FileNotFoundError):
    """The log file does not exist."""


class RosbagError(LogError):
    """A ROS bag (ROS 1 ``.bag``, rosbag2 folder, ``.db3`` or ``.mcap``) cannot be opened or read: missing,
    truncated or corrupt, or in a variant the reader does not support."""


class RosbagTopicError(RosbagError, LookupError):
    """The bag lacks the topic needed, has several candidates and none was chosen, or the chosen topic
    carries the wrong message type. ``candidates`` lists the topics that would fit."""

    def __init__(self, message: str, candidates: tuple[str, ...] = ()) -> None:
        self.candidates = tuple(candidates)
        super().__init__(message)

    def __reduce__(self) -> tuple[type[RosbagTopicError], tuple[str, tuple[str, ...]]]:
        return (type(self), (str(self), self.candidates))


class RosbagMessageError(RosbagError, ValueError):
    """A message of a bag cannot be decoded or does not describe a valid scan or pose (the message names
    the topic, the 1-based message number on that topic and the bad field)."""


class NoScansError(LogError, ValueError):
    """A log holds no scan at all (empty, only a header or comments, or not the format it was read as)."""
