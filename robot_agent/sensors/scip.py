"""SCIP 2.0, the Hokuyo URG-04LX's serial protocol: commands, replies, encodings (pure, no I/O).

After Hokuyo's "Communication Protocol Specification for SCIP2.0 Standard" (C-42-03320B): a command is a
line (two letters, parameters, an optional ``;tag`` of at most 16 characters); a reply is the echoed command
line, a status line (two characters and a checksum), data lines each ending in its checksum, and an empty
line (so every reply ends in two LFs). A checksum is the sum of the line's bytes, lower 6 bits, plus 0x30;
for the ``LABEL:value;S`` lines of VV/PP/II it covers ``LABEL:value``. Numbers are sent 6 bits per
character plus 0x30, in 2 (MS/GS ranges), 3 (MD/GD ranges) or 4 (the 24-bit millisecond time stamp)
characters; scan data is cut into lines of 64 characters. Ranges below 20 mm are error codes, not distances.
A sensor that boots in SCIP 1.1 switches on the line ``SCIP2.0``. Everything here is O(reply length).
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from robot_agent.sensors.errors import ScipChecksumError, ScipError, ScipStatusError
from shared.types import FloatArray, IntArray

__all__ = [
    "DATA_LINE_CHARS",
    "ERROR_CODE_LIMIT_MM",
    "INFO_COMMANDS",
    "SWITCH_COMMAND",
    "TIMESTAMP_MODULUS",
    "Reply",
    "ScanFrame",
    "ScanRequest",
    "angle_of_value",
    "checksum",
    "decode",
    "decode_values",
    "encode",
    "encode_reply",
    "encode_scan_reply",
    "encode_values",
    "parse_reply",
    "parse_scan_command",
    "parse_scan_reply",
    "ranges_mm_to_m",
    "recover_scan_frame",
    "status_meaning",
    "unwrap_timestamp",
]

#: Characters of scan data per line (the last line of a frame may be shorter).
DATA_LINE_CHARS = 64
#: Range values below this (mm) are the URG-04LX's error codes (0 "possibly at 22 m", 1-2 "low
#: intensity", ..., 19 "non-measurable step"), i.e. no return.
ERROR_CODE_LIMIT_MM = 20
#: The scanner's timer: 24 bits of milliseconds (wraps after about 4.66 hours).
TIMESTAMP_MODULUS = 1 << 24
#: Commands whose data lines are ``LABEL:value;checksum``.
INFO_COMMANDS = frozenset({"VV", "PP", "II"})
#: The line that switches a SCIP 1.1 sensor to SCIP 2.0.
SWITCH_COMMAND = b"SCIP2.0"

_OFFSET = 0x30
_TAG = re.compile(rb"[A-Za-z0-9 ._+@]{0,16}")
_SCAN_COMMANDS = ("MD", "MS", "GD", "GS")

_COMMON_STATUS = {
    "0A": "unable to create transmission data or reply internally",
    "0B": "buffer shortage, or a command repeated that is already being processed",
    "0C": "command with insufficient parameters",
    "0D": "undefined command",
    "0E": "undefined command",
    "0F": "command with insufficient parameters",
    "0G": "string characters in the command exceed 16 letters",
    "0H": "string characters have invalid letters",
    "0I": "sensor is in firmware update mode",
}
_SCAN_STATUS = {
    "01": "starting step has a non-numeric value",
    "02": "end step has a non-numeric value",
    "03": "cluster count has a non-numeric value",
    "04": "end step is out of range",
    "05": "end step is smaller than the starting step",
    "06": "scan interval has a non-numeric value",
    "07": "number of scans has a non-numeric value",
    "10": "laser is off (send BM first)",
    "98": "resumption after confirming normal laser operation",
}
_BM_STATUS = {"01": "unable to control the laser: laser malfunction", "02": "laser is already on"}


def status_meaning(command: str, status: str) -> str:
    """The protocol's explanation of ``status`` in reply to ``command`` (two letters). O(1)."""
    if status in _COMMON_STATUS:
        return _COMMON_STATUS[status]
    if command == "BM" and status in _BM_STATUS:
        return _BM_STATUS[status]
    if command in _SCAN_COMMANDS:
        if status in _SCAN_STATUS:
            return _SCAN_STATUS[status]
        if status.isdigit() and 21 <= int(status) <= 49:
            return "processing stopped to verify an error"
        if status.isdigit() and 50 <= int(status) <= 97:
            return "hardware trouble (laser, motor malfunction, ...)"
    return "not a status this command defines"


# ---------------------------------------------------------------------------------------------- encodings
def checksum(data: bytes) -> int:
    """The SCIP checksum character (as a byte value) of ``data``: lower 6 bits of the byte sum + 0x30."""
    return (sum(data) & 0x3F) + _OFFSET


def encode(value: int, chars: int) -> bytes:
    """``value`` in ``chars`` characters of 6 bits each, most significant first (0 <= value < 64**chars)."""
    if not 1 <= chars <= 4:
        raise ScipError(f"SCIP encoding of {chars} characters: expected 1 to 4")
    if not 0 <= value < 1 << (6 * chars):
        raise ScipError(
            f"value {value} does not fit in {chars} SCIP characters: expected 0..{(1 << (6 * chars)) - 1}"
        )
    return bytes(((value >> (6 * (chars - 1 - i))) & 0x3F) + _OFFSET for i in range(chars))


def decode(data: bytes) -> int:
    """The number encoded in ``data`` (1 to 4 characters, each in 0x30..0x6F)."""
    if not 1 <= len(data) <= 4:
        raise ScipError(f"SCIP number {data!r}: expected 1 to 4 characters")
    value = 0
    for byte in data:
        if not _OFFSET <= byte < _OFFSET + 64:
            raise ScipError(f"SCIP number {data!r}: character {chr(byte)!r} is outside '0'..'o'")
        value = (value << 6) | (byte - _OFFSET)
    return value


def decode_values(data: bytes, chars: int) -> IntArray:
    """Decode a run of ``chars``-character numbers (the joined data lines of a scan). O(len)."""
    if chars not in (2, 3, 4) or len(data) % chars:
        raise ScipError(
            f"scan data of {len(data)} characters is not a whole number of {chars}-character values"
        )
    raw = np.frombuffer(data, dtype=np.uint8).astype(np.int64) - _OFFSET
    if raw.size and (raw.min() < 0 or raw.max() > 63):
        bad = data[int(np.flatnonzero((raw < 0) | (raw > 63))[0])]
        raise ScipError(f"scan data has character {chr(bad)!r}: expected '0'..'o'")
    groups = raw.reshape(-1, chars)
    out = np.zeros(groups.shape[0], dtype=np.int64)
    for i in range(chars):
        out = (out << 6) | groups[:, i]
    return out


def encode_values(values: ArrayLike, chars: int) -> bytes:
    """Encode integers as ``chars``-character numbers, joined (the inverse of :func:`decode_values`)."""
    arr = np.asarray(values, dtype=np.int64).reshape(-1)
    if chars not in (2, 3, 4):
        raise ScipError(f"SCIP value encoding of {chars} characters: expected 2, 3 or 4")
    if arr.size and (arr.min() < 0 or arr.max() >= 1 << (6 * chars)):
        raise ScipError(f"values outside 0..{(1 << (6 * chars)) - 1} cannot be sent in {chars} characters")
    cols = [((arr >> (6 * (chars - 1 - i))) & 0x3F) + _OFFSET for i in range(chars)]
    return np.stack(cols, axis=1).astype(np.uint8).tobytes() if arr.size else b""


def ranges_mm_to_m(ranges_mm: ArrayLike) -> FloatArray:
    """Millimetres to metres, error codes (below :data:`ERROR_CODE_LIMIT_MM`) to NaN (no return)."""
    mm = np.asarray(ranges_mm, dtype=np.int64)
    out: FloatArray = np.where(mm < ERROR_CODE_LIMIT_MM, np.nan, mm / 1000.0)
    return out


def unwrap_timestamp(raw_ms: int, reference_ms: float) -> int:
    """The unwrapped time (ms) whose lower 24 bits are ``raw_ms`` nearest to ``reference_ms`` (an expected
    value, e.g. the previous stamp plus the host time elapsed since). O(1)."""
    if not 0 <= raw_ms < TIMESTAMP_MODULUS:
        raise ScipError(f"time stamp {raw_ms} ms: expected a 24-bit value")
    turns = round((reference_ms - raw_ms) / TIMESTAMP_MODULUS)
    return int(raw_ms + turns * TIMESTAMP_MODULUS)


# ---------------------------------------------------------------------------------------------- replies
@dataclass(frozen=True, slots=True)
class Reply:
    """One reply: the echoed command line, the status and the data lines (checksums checked, stripped;
    for VV/PP/II the ``;checksum`` too, so a line reads ``LABEL:value``)."""

    echo: bytes
    status: str
    lines: tuple[bytes, ...] = ()

    @property
    def command(self) -> str:
        """The two-letter command this replies to."""
        return self.echo[:2].decode("ascii", "replace")

    def check(self, *ok: str) -> Reply:
        """This reply, if its status is one of ``ok``; else :class:`ScipStatusError`."""
        if self.status not in ok:
            raise ScipStatusError(
                self.echo.decode("ascii", "replace"), self.status, status_meaning(self.command, self.status)
            )
        return self

    def fields(self) -> dict[str, str]:
        """``LABEL:value`` data lines as a mapping (VV, PP, II)."""
        out: dict[str, str] = {}
        for line in self.lines:
            label, sep, value = line.decode("latin-1").partition(":")
            if not sep:
                raise ScipError(f"{self.command} reply line {line!r}: expected LABEL:value")
            out[label] = value
        return out


def _line_error(echo: bytes, n: int, line: bytes, what: str) -> str:
    return f"SCIP reply to {echo.decode('ascii', 'replace')!r}, line {n} {line[:70]!r}: {what}"


def parse_reply(block: bytes) -> Reply:
    """Parse one reply ``block`` (ending in two LFs) and check every line's checksum.

    Raises :class:`ScipChecksumError` for a line that does not match its checksum, :class:`ScipError` for a
    malformed block. The status line of a SCIP 1.1 sensor's answer to ``SCIP2.0`` is a bare ``0``.
    """
    if not block.endswith(b"\n\n"):
        raise ScipError(f"SCIP reply {block[:40]!r}...: truncated (expected it to end in two LFs)")
    lines = block[:-2].split(b"\n")
    if len(lines) < 2 or not lines[0]:
        raise ScipError(f"SCIP reply {block[:40]!r}: expected an echo and a status line")
    echo, status_line = lines[0], lines[1]
    if echo == SWITCH_COMMAND and len(status_line) == 1:
        return Reply(echo, status_line.decode("ascii", "replace"), ())
    if len(status_line) != 3:
        raise ScipError(_line_error(echo, 2, status_line, "expected a status of 2 characters and a checksum"))
    if checksum(status_line[:2]) != status_line[2]:
        raise ScipChecksumError(_line_error(echo, 2, status_line, "status checksum does not match"))
    if not status_line[:2].isascii():
        raise ScipError(_line_error(echo, 2, status_line, "expected a status of 2 ASCII characters"))
    info = echo[:2].decode("ascii", "replace") in INFO_COMMANDS
    data: list[bytes] = []
    for n, line in enumerate(lines[2:], start=3):
        if len(line) < 2:
            raise ScipError(_line_error(echo, n, line, "expected data and a checksum"))
        if info and line[-2:-1] == b";":
            # LABEL:value;S; the checksum covers LABEL:value (some firmware includes the ';': accept both)
            if line[-1] not in (checksum(line[:-2]), checksum(line[:-1])):
                raise ScipChecksumError(_line_error(echo, n, line, "checksum does not match"))
            data.append(line[:-2])
        else:
            if line[-1] != checksum(line[:-1]):
                raise ScipChecksumError(_line_error(echo, n, line, "checksum does not match"))
            data.append(line[:-1])
    return Reply(echo, status_line[:2].decode("ascii"), tuple(data))


def encode_reply(echo: bytes, status: str, lines: Sequence[bytes] = (), *, info: bool = False) -> bytes:
    """A reply block: ``echo``, ``status`` with its checksum, each line with its checksum (``info``:
    as ``line;checksum``), and the closing empty line."""
    out = [echo, status.encode("ascii") + bytes([checksum(status.encode("ascii"))])]
    for line in lines:
        out.append(line + b";" + bytes([checksum(line)]) if info else line + bytes([checksum(line)]))
    return b"\n".join(out) + b"\n\n"


# ---------------------------------------------------------------------------------------------- scans
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
        if self.command not in _SCAN_COMMANDS:
            raise ScipError(f"scan command {self.command!r}: expected one of {', '.join(_SCAN_COMMANDS)}")
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
    if cmd not in _SCAN_COMMANDS or len(body) != 2 + sum(w for _, w in widths):
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
