"""SCIP 2.0, the Hokuyo URG-04LX's serial protocol: commands, replies, encodings (pure, no I/O).

After Hokuyo's "Communication Protocol Specification for SCIP2.0 Standard" (C-42-03320B): a command is a
line (two letters, parameters, an optional ``;tag`` of at most 16 characters); a reply is the echoed command
line, a status line (two characters and a checksum), data lines each ending in its checksum, and an empty
line (so every reply ends in two LFs). A checksum is the sum of the line's bytes, lower 6 bits, plus 0x30;
for the ``LABEL:value;S`` lines of VV/PP/II it covers ``LABEL:value``. Numbers are sent 6 bits per
character plus 0x30, in 2 (MS/GS ranges), 3 (MD/GD ranges) or 4 (the 24-bit millisecond time stamp)
characters; scan data is cut into lines of 64 characters. Ranges below 20 mm are error codes, not distances.
A sensor that boots in SCIP 1.1 switches on the line ``SCIP2.0``. Everything here is O(reply length).

This module is the framing (replies, checksums, status codes) and the number encodings; the scan
commands and their data frames are :mod:`robot_agent.sensors.scip_scan`, the VV/PP/II replies
:mod:`robot_agent.sensors.scip_info`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from robot_agent.sensors.errors import ScipChecksumError, ScipError, ScipStatusError
from shared.types import FloatArray, IntArray

__all__ = [
    "DATA_LINE_CHARS",
    "ERROR_CODE_LIMIT_MM",
    "INFO_COMMANDS",
    "SCAN_COMMANDS",
    "SWITCH_COMMAND",
    "TIMESTAMP_MODULUS",
    "Reply",
    "checksum",
    "decode",
    "decode_values",
    "encode",
    "encode_reply",
    "encode_values",
    "parse_reply",
    "ranges_mm_to_m",
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
#: The scan commands (:mod:`robot_agent.sensors.scip_scan`).
SCAN_COMMANDS = ("MD", "MS", "GD", "GS")

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
    if command in SCAN_COMMANDS:
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
