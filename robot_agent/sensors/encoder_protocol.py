"""The encoder bridge's wire protocol (version 1) and its host-side decoder, with no I/O.

Records, line parser and formatter, checksum, counter wrap (O(line length)), the bridge-to-host clock map
and the decoder that turns lines into odometry poses (O(1) per line). The grammar and the host's rules are
described in :mod:`robot_agent.sensors.encoders` (``E <t_ms> <left_ticks> <right_ticks>[*HH]``,
``I <ticks_per_rev> <wheel_diameter_mm> <tread_mm> <firmware>[*HH]``, ``# comment``; the host sends ``?``).
"""

from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass, field

from robot_agent.sensors.errors import SensorError
from shared.odometry import DiffDrive
from shared.types import Pose2D

__all__ = [
    "HELLO",
    "MAX_LINE_BYTES",
    "BridgeInfo",
    "ClockSync",
    "EncoderDecoder",
    "EncoderError",
    "EncoderLine",
    "EncoderProtocolError",
    "EncoderStats",
    "LineSplitter",
    "OdometryReading",
    "checksum",
    "format_line",
    "parse_line",
    "tick_delta",
    "wrap_int32",
]

_log = logging.getLogger(__name__)

#: What the host sends to ask for the ``I`` line.
HELLO = b"?\n"
MAX_LINE_BYTES = 128
_U32 = 1 << 32
_I32_MIN, _I32_MAX = -(1 << 31), (1 << 31) - 1
_UINT = re.compile(r"[0-9]{1,10}")
_SINT = re.compile(r"-?[0-9]{1,10}")
_NUMBER = re.compile(r"[0-9]+(\.[0-9]+)?([eE][+-]?[0-9]+)?")
_FIRMWARE = re.compile(r"[!-)+-~]{1,32}")  # printable, no space, no '*'
_HEX2 = re.compile(r"[0-9A-Fa-f]{2}")


class EncoderError(SensorError):
    """The wheel-encoder source cannot be opened or read (port missing, bridge silent or gone)."""


class EncoderProtocolError(EncoderError, ValueError):
    """A line or record that does not follow the bridge protocol; ``kind`` is the short reason counted in
    :class:`EncoderStats` (e.g. ``"bad checksum"``), the message says what was wrong and what was expected."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


def wrap_int32(value: int) -> int:
    """``value`` as a signed 32-bit two's-complement counter would hold it. O(1)."""
    return ((value - _I32_MIN) % _U32) + _I32_MIN


def tick_delta(new: int, old: int) -> int:
    """Signed change of a wrapping 32-bit counter from ``old`` to ``new`` (|change| < 2^31). O(1)."""
    return wrap_int32(new - old)


@dataclass(frozen=True, slots=True)
class EncoderLine:
    """An ``E`` record as sent: bridge time (ms, unsigned 32-bit) and the two cumulative signed 32-bit
    tick counters."""

    device_ms: int
    left_ticks: int
    right_ticks: int

    def __post_init__(self) -> None:
        _check_int("t_ms", self.device_ms, 0, _U32 - 1)
        _check_int("left_ticks", self.left_ticks, _I32_MIN, _I32_MAX)
        _check_int("right_ticks", self.right_ticks, _I32_MIN, _I32_MAX)


@dataclass(frozen=True, slots=True)
class BridgeInfo:
    """An ``I`` record: encoder ticks per wheel revolution, wheel diameter and tread (mm), firmware."""

    ticks_per_rev: float
    wheel_diameter_mm: float
    tread_mm: float
    firmware: str

    def __post_init__(self) -> None:
        for name in ("ticks_per_rev", "wheel_diameter_mm", "tread_mm"):
            value = getattr(self, name)
            if (
                isinstance(value, bool)
                or not isinstance(value, (int, float))
                or not (math.isfinite(value) and value > 0)
            ):
                raise EncoderProtocolError("out of range", f"{name} = {value!r}: expected a positive number")
            object.__setattr__(self, name, float(value))
        if not (isinstance(self.firmware, str) and _FIRMWARE.fullmatch(self.firmware)):
            raise EncoderProtocolError(
                "bad field",
                f"firmware = {self.firmware!r}: expected 1-32 printable ASCII characters, no space or '*'",
            )

    def to_drive(self, laser_offset: Pose2D | None = None) -> DiffDrive:
        """The robot geometry this bridge reports, in metres (the laser offset is not in the protocol)."""
        return DiffDrive(
            wheel_diameter_m=self.wheel_diameter_mm / 1000.0,
            tread_m=self.tread_mm / 1000.0,
            ticks_per_turn=self.ticks_per_rev,
            laser_offset=laser_offset if laser_offset is not None else Pose2D(),
        )


def _check_int(name: str, value: int, low: int, high: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise EncoderProtocolError(
            "out of range", f"{name} = {value!r}: expected an integer in {low}..{high}"
        )


def checksum(payload: bytes) -> int:
    """NMEA-style checksum: the XOR of all bytes of ``payload`` (everything before the ``*``). O(len)."""
    value = 0
    for byte in payload:
        value ^= byte
    return value


def _number(value: float) -> str:
    text = repr(float(value))
    return text[:-2] if text.endswith(".0") else text


def format_line(record: EncoderLine | BridgeInfo, *, with_checksum: bool = True) -> bytes:
    """The protocol line for ``record``, LF included; :func:`parse_line` gives ``record`` back. O(1)."""
    if isinstance(record, EncoderLine):
        text = f"E {record.device_ms} {record.left_ticks} {record.right_ticks}"
    else:
        text = (
            f"I {_number(record.ticks_per_rev)} {_number(record.wheel_diameter_mm)} "
            f"{_number(record.tread_mm)} {record.firmware}"
        )
    payload = text.encode("ascii")
    if with_checksum:
        payload += b"*%02X" % checksum(payload)
    return payload + b"\n"


def parse_line(line: bytes | str, *, require_checksum: bool = False) -> EncoderLine | BridgeInfo | None:
    """Parse one protocol line (with or without its line ending). O(len).

    Returns the record, or None for a blank line or a ``#`` comment; raises :class:`EncoderProtocolError`
    naming what is wrong for anything else (see the module docstring for the grammar).
    """
    raw = line.encode("utf-8", "replace") if isinstance(line, str) else bytes(line)
    for ending in (b"\r\n", b"\n", b"\r"):
        if raw.endswith(ending):
            raw = raw[: -len(ending)]
            break
    if len(raw) > MAX_LINE_BYTES:
        raise EncoderProtocolError(
            "too long", f"line of {len(raw)} bytes {raw[:24]!r}...: expected at most {MAX_LINE_BYTES}"
        )
    bad = next((b for b in raw if not 0x20 <= b <= 0x7E), None)
    if bad is not None:
        raise EncoderProtocolError(
            "bad byte", f"line {raw!r} holds byte 0x{bad:02X}: expected printable ASCII (0x20-0x7E) only"
        )
    text = raw.decode("ascii")
    if not text.strip() or text.lstrip().startswith("#"):
        return None
    payload, star, given = text.rpartition("*")
    if star:
        if not _HEX2.fullmatch(given):
            raise EncoderProtocolError(
                "bad checksum", f"line {text!r}: expected '*' and two hex digits at its end"
            )
        expected = checksum(payload.encode("ascii"))
        if int(given, 16) != expected:
            raise EncoderProtocolError(
                "bad checksum", f"line {text!r}: checksum *{given} does not match the line's *{expected:02X}"
            )
        if "*" in payload:
            raise EncoderProtocolError("bad field", f"line {text!r}: '*' inside the line")
    else:
        payload = text
        if require_checksum:
            raise EncoderProtocolError("missing checksum", f"line {text!r}: expected a '*HH' checksum")
    fields = payload.split()
    kind, args = fields[0], fields[1:]
    if kind == "E":
        if len(args) != 3:
            raise EncoderProtocolError(
                "field count", f"line {text!r}: expected 'E <t_ms> <left_ticks> <right_ticks>'"
            )
        for name, value, pattern in zip(
            ("t_ms", "left_ticks", "right_ticks"), args, (_UINT, _SINT, _SINT), strict=True
        ):
            if not pattern.fullmatch(value):
                raise EncoderProtocolError(
                    "bad number", f"line {text!r}: {name} = {value!r} is not an integer"
                )
        return EncoderLine(int(args[0]), int(args[1]), int(args[2]))
    if kind == "I":
        if len(args) != 4:
            raise EncoderProtocolError(
                "field count",
                f"line {text!r}: expected 'I <ticks_per_rev> <wheel_diameter_mm> <tread_mm> <firmware>'",
            )
        for name, value in zip(("ticks_per_rev", "wheel_diameter_mm", "tread_mm"), args, strict=False):
            if not _NUMBER.fullmatch(value):
                raise EncoderProtocolError("bad number", f"line {text!r}: {name} = {value!r} is not a number")
        return BridgeInfo(float(args[0]), float(args[1]), float(args[2]), args[3])
    raise EncoderProtocolError("unknown record", f"line {text!r}: expected an 'E', 'I' or '#' line")


class LineSplitter:
    """Splits a byte stream into lines at LF. A line longer than :data:`MAX_LINE_BYTES` is cut to
    ``MAX_LINE_BYTES + 1`` bytes (so :func:`parse_line` rejects it as too long) and the rest of it dropped,
    keeping memory bounded. Amortised O(1) per byte."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self._overlong = False

    def feed(self, data: bytes) -> list[bytes]:
        """The complete lines (without LF) that ``data`` finishes, in order."""
        lines: list[bytes] = []
        start = 0
        while (end := data.find(b"\n", start)) >= 0:
            self._append(data[start:end])
            lines.append(bytes(self._buf))
            self._buf.clear()
            self._overlong = False
            start = end + 1
        self._append(data[start:])
        return lines

    def _append(self, chunk: bytes) -> None:
        if self._overlong:
            return
        self._buf += chunk
        if len(self._buf) > MAX_LINE_BYTES + 2:  # room for CR LF
            del self._buf[MAX_LINE_BYTES + 1 :]
            self._overlong = True


class ClockSync:
    """Maps bridge time to host time (s): ``host = device + offset``. O(1) per update.

    ``offset`` is the running minimum of ``host_rx - device`` over the readings (the least-delayed one
    bounds the true offset from above), allowed to rise by ``max_drift`` seconds per second of bridge time
    so that a bridge clock running slower than the host's is followed too. With the bridge's true latch
    time ``T`` on the host clock, every estimate satisfies ``T <= stamp <= host_rx`` as long as the bridge
    clock drifts by less than ``max_drift``.
    """

    def __init__(self, max_drift: float = 1e-3) -> None:
        self.max_drift = max_drift
        self._offset: float | None = None
        self._device_s = 0.0

    def update(self, device_s: float, host_rx_s: float) -> float:
        """The host time of a reading latched at ``device_s`` (increasing) and received at ``host_rx_s``."""
        candidate = host_rx_s - device_s
        if self._offset is None:
            offset = candidate
        else:
            offset = min(candidate, self._offset + self.max_drift * (device_s - self._device_s))
        self._offset, self._device_s = offset, device_s
        return device_s + offset


@dataclass(frozen=True, slots=True)
class OdometryReading:
    """One decoded wheel reading: host time (s), raw bridge time (ms), the left/right tick counts since the
    first reading (unwrapped) and the robot pose integrated from them (odometry frame, robot not laser)."""

    stamp_s: float
    device_ms: int
    left_ticks: int
    right_ticks: int
    pose: Pose2D


@dataclass(slots=True)
class EncoderStats:
    """What a decoder saw: lines, readings produced, bad lines per reason, bridge restarts, readings
    dropped because the consumer fell behind, and the bridge's last ``I`` line."""

    lines: int = 0
    readings: int = 0
    malformed: int = 0
    reasons: dict[str, int] = field(default_factory=dict)
    resets: int = 0
    dropped: int = 0
    info: BridgeInfo | None = None


class EncoderDecoder:
    """Turns protocol lines into :class:`OdometryReading` poses: counter and clock wrap, bridge restarts,
    host time (:class:`ClockSync`) and eq. 9-11 through :meth:`DiffDrive.step_ticks`. O(1) per line.

    Shared by the serial and the simulated source, so both give the same readings for the same lines.
    ``require_checksum=None`` (the default) requires checksums once the bridge has sent one good
    checksummed line: a line that lost its ``*`` to noise could otherwise pass as a valid unchecked one.
    """

    def __init__(
        self,
        drive: DiffDrive,
        *,
        origin: Pose2D | None = None,
        midpoint: bool = True,
        require_checksum: bool | None = None,
        max_wheel_speed_mps: float | None = 5.0,
        max_drift: float = 1e-3,
    ) -> None:
        self.drive = drive
        self.midpoint = midpoint
        self.require_checksum = require_checksum
        self.max_wheel_speed_mps = max_wheel_speed_mps
        self.max_drift = max_drift
        self.stats = EncoderStats()
        self._pose = origin if origin is not None else Pose2D()
        self._last: EncoderLine | None = None
        self._epoch_ms = 0
        self._left = self._right = 0
        self._sync = ClockSync(max_drift)
        self._stamp_s = -math.inf
        self._implausible = 0
        self._checksummed = False

    def feed_line(self, line: bytes, host_rx_s: float) -> OdometryReading | BridgeInfo | None:
        """Parse and decode one line received at ``host_rx_s``; a bad line is counted, logged, skipped."""
        self.stats.lines += 1
        try:
            required = self._checksummed if self.require_checksum is None else self.require_checksum
            record = parse_line(line, require_checksum=required)
        except EncoderProtocolError as exc:
            self.reject(exc)
            return None
        if record is None:
            _log.debug("encoder bridge: %r", line)
            return None
        if not self._checksummed and b"*" in line:  # only a checksum can hold '*' in a good E or I line
            self._checksummed = True
        if isinstance(record, BridgeInfo):
            self.stats.info = record
            return record
        return self.feed(record, host_rx_s)

    def feed(self, record: EncoderLine, host_rx_s: float) -> OdometryReading | None:
        """Decode one ``E`` record received at ``host_rx_s`` (host clock, s); None if it was skipped."""
        prev = self._last
        if prev is not None:
            dt_ms = (record.device_ms - prev.device_ms) % _U32
            if dt_ms == 0:
                self.reject(EncoderProtocolError("time not advancing", f"{record}: same t_ms as the last"))
                return None
            if dt_ms >= _U32 // 2:
                _log.warning("encoder bridge time went back (%s after %s): bridge restarted", record, prev)
                self._restart()
                prev = None
        if prev is None:
            d_left = d_right = 0
        else:
            d_left = tick_delta(record.left_ticks, prev.left_ticks)
            d_right = tick_delta(record.right_ticks, prev.right_ticks)
            limit = self.max_wheel_speed_mps
            speed = max(abs(d_left), abs(d_right)) * self.drive.metres_per_tick / (dt_ms / 1000.0)
            if limit is not None and speed > limit:
                self._implausible += 1
                if self._implausible < 3:
                    self.reject(
                        EncoderProtocolError(
                            "implausible jump",
                            f"{record} after {prev}: a wheel at {speed:.3g} m/s, expected <= {limit} m/s",
                        )
                    )
                    return None
                _log.warning("encoder counts jumped 3 times in a row: taking %s as a new baseline", record)
                self.stats.resets += 1
                d_left = d_right = 0
            self._epoch_ms += dt_ms
        self._implausible = 0
        self._last = record
        self._left += d_left
        self._right += d_right
        if prev is not None:
            self._pose = self.drive.step_ticks(self._pose, d_left, d_right, self.midpoint)
        stamp = max(self._sync.update(self._epoch_ms / 1000.0, host_rx_s), self._stamp_s + 1e-6)
        self._stamp_s = stamp
        self.stats.readings += 1
        return OdometryReading(stamp, record.device_ms, self._left, self._right, self._pose)

    def _restart(self) -> None:
        self.stats.resets += 1
        self._sync = ClockSync(self.max_drift)
        self._epoch_ms = 0

    def reject(self, exc: EncoderProtocolError) -> None:
        """Count and log a bad line (warnings for the first 10 and then every 1000th, debug otherwise)."""
        stats = self.stats
        stats.malformed += 1
        stats.reasons[exc.kind] = stats.reasons.get(exc.kind, 0) + 1
        level = logging.WARNING if stats.malformed <= 10 or stats.malformed % 1000 == 0 else logging.DEBUG
        _log.log(level, "encoder line skipped (%d so far): %s", stats.malformed, exc)
