"""SCIP 2.0 scans (pure, no I/O): the scan commands MD/MS/GD/GS, their data frames and the angles of their
values, after Hokuyo's "Communication Protocol Specification for SCIP2.0 Standard" (C-42-03320B).

A scan command is ``MD``/``MS`` (continuous: 3/2-character ranges) or ``GD``/``GS`` (one scan) with its
start and end steps, cluster count, for MD/MS the scan interval and number of scans, and an optional tag.
A data frame is a reply (:mod:`robot_agent.sensors.scip`: framing, checksums, number encodings) whose
first data line is the 4-character 24-bit time stamp (ms) and whose other lines carry the range values
(mm) in lines of :data:`~robot_agent.sensors.scip.DATA_LINE_CHARS` characters; a damaged frame may be
recovered from the next one that ran into it. Angles in rad. Everything here is O(reply length).
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from dataclasses import dataclass

from numpy.typing import ArrayLike

from robot_agent.sensors.errors import ScipError, ScipStatusError
from robot_agent.sensors.scip import (
    DATA_LINE_CHARS,
    SCAN_COMMANDS,
    TIMESTAMP_MODULUS,
    Reply,
    decode,
    decode_values,
    encode,
    encode_reply,
    encode_values,
    parse_reply,
    ranges_mm_to_m,
)
from shared.types import FloatArray, IntArray

__all__ = [
    "ScanFrame",
    "ScanRequest",
    "angle_of_value",
    "encode_scan_reply",
    "parse_scan_command",
    "parse_scan_reply",
    "recover_scan_frame",
]

_TAG = re.compile(rb"[A-Za-z0-9 ._+@]{0,16}")


@dataclass(frozen=True, slots=True)
class ScanRequest:
    """A scan command: MD/MS (continuous, 3/2-character ranges) or GD/GS (one scan).

    Steps ``start_step..end_step`` inclusive; ``cluster`` adjacent steps merged into one value (0 and 1:
    none); ``interval`` scans skipped between two sent (MD/MS); ``scans`` to send (MD/MS, 0: until QT);
    ``tag``: optional string characters echoed back.
    """

    command: str
    start_step: int
    end_step: int
    cluster: int = 1
    interval: int = 0
    scans: int = 0
    tag: str = ""

    def __post_init__(self) -> None:
        if self.command not in SCAN_COMMANDS:
            raise ScipError(f"scan command {self.command!r}: expected one of {', '.join(SCAN_COMMANDS)}")
        for name, low, high in (
            ("start_step", 0, 9999),
            ("end_step", 0, 9999),
            ("cluster", 0, 99),
            ("interval", 0, 9),
            ("scans", 0, 99),
        ):
            value = getattr(self, name)
            if not (isinstance(value, int) and low <= value <= high):
                raise ScipError(f"{self.command} {name} = {value!r}: expected an integer in {low}..{high}")
        if self.end_step < self.start_step:
            raise ScipError(f"{self.command} end_step {self.end_step} < start_step {self.start_step}")
        if not _TAG.fullmatch(self.tag.encode("ascii", "replace")):
            raise ScipError(
                f"{self.command} tag {self.tag!r}: expected up to 16 of A-Z a-z 0-9 space . _ + @"
            )

    @property
    def continuous(self) -> bool:
        """MD/MS (True) or GD/GS."""
        return self.command[0] == "M"

    @property
    def chars(self) -> int:
        """Characters per range value: 3 (MD/GD) or 2 (MS/GS)."""
        return 3 if self.command[1] == "D" else 2

    @property
    def group(self) -> int:
        """Steps per value (the cluster count, at least 1)."""
        return max(self.cluster, 1)

    @property
    def value_count(self) -> int:
        """Range values in one scan."""
        return -(-(self.end_step - self.start_step + 1) // self.group)

    def echo_prefix(self) -> bytes:
        """The echo of this request's data frames up to (not including) the remaining-scans field."""
        head = f"{self.command}{self.start_step:04d}{self.end_step:04d}{self.cluster:02d}"
        return (head + (f"{self.interval:01d}" if self.continuous else "")).encode("ascii")

    def line(self, remaining: int | None = None) -> bytes:
        """The command line (no LF); for MD/MS the remaining-scans field is ``remaining`` if given."""
        count = self.scans if remaining is None else remaining
        tail = f"{count:02d}".encode("ascii") if self.continuous else b""
        return self.echo_prefix() + tail + (b";" + self.tag.encode("ascii") if self.tag else b"")


def parse_scan_command(line: bytes) -> tuple[ScanRequest | None, str]:
    """A scan command line (or a frame's echo) as ``(request, "00")``, or ``(None, status)`` with the
    status code SCIP defines for what is wrong (01..07, 0C)."""
    body, _, tag = line.partition(b";")
    cmd = body[:2].decode("ascii", "replace")
    widths = [("01", 4), ("02", 4), ("03", 2)] + ([("06", 1), ("07", 2)] if cmd[:1] == "M" else [])
    if cmd not in SCAN_COMMANDS or len(body) != 2 + sum(w for _, w in widths):
        return None, "0C"
    fields, pos = [], 2
    for code, width in widths:
        text = body[pos : pos + width]
        pos += width
        if not text.isdigit():
            return None, code
        fields.append(int(text))
    start, end, cluster = fields[:3]
    interval, scans = (fields[3], fields[4]) if len(fields) == 5 else (0, 0)
    if end < start:
        return None, "05"
    try:
        return ScanRequest(cmd, start, end, cluster, interval, scans, tag.decode("ascii")), "00"
    except (ScipError, UnicodeDecodeError):
        return None, "0H"


@dataclass(frozen=True, slots=True)
class ScanFrame:
    """One scan as sent: the request echoed, remaining scans (MD/MS), the raw 24-bit time stamp (ms) and
    the raw range values (mm; below 20 they are error codes)."""

    request: ScanRequest
    remaining: int
    timestamp_ms: int
    ranges_mm: IntArray

    def ranges_m(self) -> FloatArray:
        """Ranges in metres, NaN for error codes."""
        return ranges_mm_to_m(self.ranges_mm)


def parse_scan_reply(reply: Reply, expected: ScanRequest | None = None) -> ScanFrame:
    """The scan in ``reply`` (an MD/MS data frame, status 99, or a GD/GS reply, status 00).

    Checks the echo against ``expected`` (steps, cluster, interval), every data line but the last being
    64 characters and the value count, so a truncated or merged frame is refused (:class:`ScipError`).
    """
    request, status = parse_scan_command(reply.echo)
    if request is None:
        raise ScipError(f"scan reply echo {reply.echo!r}: not a scan command (status {status})")
    reply.check("99" if request.continuous else "00")
    if expected is not None and request.echo_prefix() != expected.echo_prefix():
        raise ScipError(f"scan reply echo {reply.echo!r}: expected {expected.echo_prefix()!r}..")
    if len(reply.lines) < 2 or len(reply.lines[0]) != 4:
        raise ScipError(f"scan reply to {reply.echo!r}: expected a 4-character time stamp line and data")
    data = reply.lines[1:]
    if any(len(line) != DATA_LINE_CHARS for line in data[:-1]) or not 0 < len(data[-1]) <= DATA_LINE_CHARS:
        raise ScipError(f"scan reply to {reply.echo!r}: data lines are not of {DATA_LINE_CHARS} characters")
    payload = b"".join(data)
    if len(payload) != request.value_count * request.chars:
        raise ScipError(
            f"scan reply to {reply.echo!r} has {len(payload)} data characters: expected "
            f"{request.value_count} values of {request.chars}"
        )
    remaining = request.scans if request.continuous else 0
    ranges = decode_values(payload, request.chars)
    ranges.setflags(write=False)
    return ScanFrame(request, remaining, decode(reply.lines[0]), ranges)


def _tails(block: bytes, prefix: bytes) -> Iterator[bytes]:
    start = block.find(prefix, 1)
    while start >= 0:
        yield block[start:]
        start = block.find(prefix, start + 1)


def recover_scan_frame(block: bytes, expected: ScanRequest) -> ScanFrame | None:
    """The intact frame inside a damaged ``block``, if any: a truncated frame runs into the next one, whose
    echo then starts somewhere inside the block. None if no later frame parses. O(len x occurrences)."""
    for tail in _tails(block, expected.echo_prefix()):
        try:
            return parse_scan_reply(parse_reply(tail), expected)
        except (ScipError, ScipStatusError):
            continue
    return None


def encode_scan_reply(
    request: ScanRequest, timestamp_ms: int, values: ArrayLike, *, remaining: int | None = None
) -> bytes:
    """The frame a sensor sends for ``request`` (MD/MS: status 99, echo with ``remaining``; GD/GS: 00)."""
    payload = encode_values(values, request.chars)
    if len(payload) != request.value_count * request.chars:
        raise ScipError(f"{len(payload) // request.chars} values for {request.value_count} expected")
    stamp = encode(timestamp_ms % TIMESTAMP_MODULUS, 4)
    blocks = [payload[i : i + DATA_LINE_CHARS] for i in range(0, len(payload), DATA_LINE_CHARS)]
    status = "99" if request.continuous else "00"
    return encode_reply(request.line(remaining), status, [stamp, *blocks])


def angle_of_value(request: ScanRequest, front_step: int, steps_per_turn: int) -> tuple[float, float]:
    """``(angle_min_rad, angle_increment_rad)`` of the values of ``request``: a cluster of steps sits at
    its middle step's angle, so the increment is ``cluster`` steps. O(1)."""
    inc = 2.0 * math.pi / steps_per_turn
    first = request.start_step + (request.group - 1) / 2.0
    return (first - front_step) * inc, request.group * inc
