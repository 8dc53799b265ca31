"""The host side of the encoder bridge (protocol version 1): lines in, odometry poses out, with no I/O.

:class:`EncoderDecoder` parses each line (:mod:`robot_agent.sensors.encoder_protocol`: records, checksum,
counter wrap), unwraps the 32-bit tick counters and the bridge's millisecond clock, detects bridge restarts
and implausible jumps, maps bridge time to host time (:class:`ClockSync`, s) and integrates the pose with
the paper's eq. 9-11 (:meth:`shared.odometry.DiffDrive.step_ticks`; m, rad). O(1) per line.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

from robot_agent.sensors.encoder_protocol import (
    BridgeInfo,
    EncoderLine,
    EncoderProtocolError,
    parse_line,
    tick_delta,
)
from shared.odometry import DiffDrive
from shared.types import Pose2D

__all__ = ["ClockSync", "EncoderDecoder", "EncoderStats", "OdometryReading"]

_log = logging.getLogger(__name__)

#: The bridge's clock and counters wrap at 32 bits.
_U32 = 1 << 32


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
