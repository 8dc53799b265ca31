"""Hokuyo URG-04LX driver: SCIP 2.0 over a serial port (pyserial), scans as :class:`shared.types.Scan`.

``UrgDriver(port)`` opens the port (a device path, or any pyserial URL), switches a SCIP 1.1 sensor to
SCIP 2.0, stops any scan stream left running and reads the sensor's parameters (PP). ``scans()`` streams MD
frames as scans in metres (docs/design.md §3): angles from AMIN/AFRT/ARES (a cluster of steps at its middle
step, the increment ``cluster`` steps), the range window DMIN..DMAX, error codes (< 20 mm) as NaN, and the
sensor's 24-bit millisecond stamps mapped to host seconds (:mod:`robot_agent.sensors.urg_scans`).

Recovery: a frame with a bad checksum or truncated is dropped (counted in ``stats``, logged) and reading
goes on at the next frame, including one that ran into the damaged one; a read timeout or a vanished device
(unplugged: the port path disappears, reads fail) closes the port, reopens it with exponential backoff
(bounded delay; ``stop`` ends the wait, ``give_up_after_s`` bounds it) and restarts MD. The first open
does not retry: a wrong path fails at once, with the reason.

One thread drives a driver; the other commands must not be called while a ``scans()`` iterator is live.
This module is the device session only: the protocol is :mod:`~robot_agent.sensors.scip` (framing),
:mod:`~robot_agent.sensors.scip_scan` (scan frames) and :mod:`~robot_agent.sensors.scip_info` (VV/PP/II).
"""

from __future__ import annotations

import errno
import logging
import os
import threading
import time
from collections.abc import Callable, Generator, Iterator
from dataclasses import dataclass, replace
from typing import Any

import serial  # type: ignore[import-untyped]

from robot_agent.sensors.errors import (
    ScipError,
    SensorDisconnectedError,
    SensorError,
    SensorTimeoutError,
)
from robot_agent.sensors.scip import SWITCH_COMMAND, Reply, parse_reply
from robot_agent.sensors.scip_info import (
    SensorParams,
    SensorState,
    VersionInfo,
    parse_parameters,
    parse_state,
    parse_switch_reply,
    parse_versions,
)
from robot_agent.sensors.scip_scan import (
    ScanFrame,
    ScanRequest,
    parse_scan_reply,
    recover_scan_frame,
)
from robot_agent.sensors.urg_scans import ClockMapper, scan_from_frame
from shared.types import Scan

__all__ = ["UrgDriver", "UrgStats"]

log = logging.getLogger(__name__)

_MAX_BUFFER = 1 << 16  # bytes without a reply end: garbage, dropped


@dataclass
class UrgStats:
    """What the driver has seen: scans delivered, damaged frames dropped, reconnections, failed opens."""

    scans: int = 0
    dropped_frames: int = 0
    reconnects: int = 0
    open_failures: int = 0
    last_error: str = ""


def _why(exc: BaseException) -> str:
    """The reason a port did not open, in words an operator can act on."""
    code = getattr(exc, "errno", None)
    if code == errno.ENOENT:
        return "no such device (is the scanner plugged in? expected e.g. /dev/ttyACM0)"
    if code in (errno.EACCES, errno.EPERM):
        return "permission denied (add the user to the 'dialout' group)"
    if code == errno.EBUSY:
        return "the device is busy (another program has it open)"
    return os.strerror(code) if isinstance(code, int) else str(exc)


class UrgDriver:
    """A URG-04LX on ``port`` (see the module docstring). Use as a context manager or open()/close().

    ``timeout_s`` bounds every reply and the gap between two scan frames; ``backoff_s`` (doubling up to
    ``backoff_max_s``) paces reconnection attempts; ``give_up_after_s`` (None: never) ends them with
    :class:`SensorDisconnectedError`; ``stop`` set ends a ``scans()`` stream. ``clock`` gives host seconds.
    """

    def __init__(
        self,
        port: str,
        baudrate: int = 115200,
        timeout_s: float = 1.0,
        *,
        reconnect: bool = True,
        backoff_s: float = 0.05,
        backoff_max_s: float = 2.0,
        give_up_after_s: float | None = None,
        stop: threading.Event | None = None,
        clock: Callable[[], float] = time.time,
    ) -> None:
        if not port:
            raise SensorDisconnectedError("URG-04LX: no serial port given (expected e.g. /dev/ttyACM0)")
        if not (timeout_s > 0 and backoff_s > 0 and backoff_max_s >= backoff_s):
            raise SensorError(
                f"URG-04LX timeout_s {timeout_s}, backoff_s {backoff_s}, backoff_max_s {backoff_max_s}: "
                "expected positive values with backoff_max_s >= backoff_s"
            )
        self.port = port
        self.baudrate = baudrate
        self.timeout_s = timeout_s
        self.reconnect = reconnect
        self.backoff_s = backoff_s
        self.backoff_max_s = backoff_max_s
        self.give_up_after_s = give_up_after_s
        self.stop = stop or threading.Event()
        self.clock = clock
        self.stats = UrgStats()
        self.params: SensorParams | None = None
        self.switched_from_scip1 = False
        self._serial: Any = None
        self._buf = bytearray()
        self._gd_clock = ClockMapper()

    # ------------------------------------------------------------------ connection
    def __enter__(self) -> UrgDriver:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def is_open(self) -> bool:
        """Whether the port is open."""
        return self._serial is not None

    def open(self) -> None:
        """Open the port, switch to SCIP 2.0, stop any running stream, read PP. No retry."""
        if self._serial is not None:
            return
        try:
            port = serial.serial_for_url(
                self.port, baudrate=self.baudrate, timeout=min(0.1, self.timeout_s), do_not_open=True
            )
            port.write_timeout = self.timeout_s
            port.open()
        except (serial.SerialException, OSError, ValueError) as exc:
            raise SensorDisconnectedError(f"cannot open serial port {self.port!r}: {_why(exc)}") from None
        self._serial, self._buf = port, bytearray()
        try:
            try:
                switch = self._transact(SWITCH_COMMAND)
            except SensorTimeoutError as exc:
                raise SensorTimeoutError(f"{exc} (is a URG-04LX on {self.port}, powered?)") from None
            self.switched_from_scip1 = parse_switch_reply(switch)
            if self.switched_from_scip1:
                log.info("URG-04LX at %s: switched from SCIP 1.1 to SCIP 2.0", self.port)
            self._transact(b"QT").check("00")
            self.params = parse_parameters(self._transact(b"PP"))
        except BaseException:
            self._drop_port()
            raise
        log.info("URG-04LX at %s: open, %s", self.port, self.params.model)

    def close(self) -> None:
        """Stop the laser (best effort) and close the port."""
        if self._serial is None:
            return
        try:
            self._transact(b"QT")
        except SensorError as exc:
            log.debug("URG-04LX at %s: QT on close failed: %s", self.port, exc)
        self._drop_port()

    def _drop_port(self) -> None:
        port, self._serial = self._serial, None
        if port is not None:
            try:
                port.close()
            except (serial.SerialException, OSError) as exc:
                log.debug("URG-04LX at %s: close failed: %s", self.port, exc)

    # ------------------------------------------------------------------ I/O
    def _write(self, line: bytes) -> None:
        if self._serial is None:
            raise SensorDisconnectedError(f"URG-04LX at {self.port}: not open")
        try:
            self._serial.write(line + b"\n")
        except serial.SerialTimeoutException:
            raise SensorTimeoutError(f"URG-04LX at {self.port}: writing {line!r} timed out") from None
        except (serial.SerialException, OSError) as exc:
            raise SensorDisconnectedError(f"URG-04LX at {self.port}: write failed: {exc}") from None

    def _read_block(self, deadline: float, what: str) -> bytes:
        """The next block of bytes up to and including two LFs (one reply or frame)."""
        while True:
            while self._buf[:1] == b"\n":
                del self._buf[:1]
            end = self._buf.find(b"\n\n")
            if end >= 0:
                block = bytes(self._buf[: end + 2])
                del self._buf[: end + 2]
                return block
            if len(self._buf) > _MAX_BUFFER:
                log.warning(
                    "URG-04LX at %s: %d bytes without a reply end, dropped", self.port, len(self._buf)
                )
                self._buf.clear()
            if time.monotonic() > deadline:
                raise SensorTimeoutError(f"URG-04LX at {self.port}: no {what} within {self.timeout_s:g} s")
            if self._serial is None:
                raise SensorDisconnectedError(f"URG-04LX at {self.port}: not open")
            try:
                chunk = self._serial.read(max(1, self._serial.in_waiting))
            except (serial.SerialException, OSError) as exc:
                raise SensorDisconnectedError(f"URG-04LX at {self.port}: read failed: {exc}") from None
            self._buf += chunk

    def _transact(self, line: bytes) -> Reply:
        """Send ``line``; the reply whose echo is ``line``, skipping anything else (frames of a stream
        still running, stale replies); a reply glued to garbage is found by its echo."""
        self._write(line)
        deadline = time.monotonic() + self.timeout_s
        what = f"reply to {line.decode('ascii', 'replace')!r}"
        while True:
            block = self._read_block(deadline, what)
            start = block.find(line + b"\n")
            if start < 0:
                log.debug("URG-04LX at %s: skipped %r while waiting for %r", self.port, block[:30], line)
                continue
            return parse_reply(block[start:])

    def _command(self, line: bytes, *ok: str) -> Reply:
        self.open()
        return self._transact(line).check(*ok)

    # ------------------------------------------------------------------ commands
    def versions(self) -> VersionInfo:
        """VV: vendor, product, firmware, protocol, serial number."""
        return parse_versions(self._command(b"VV", "00"))

    def parameters(self, refresh: bool = False) -> SensorParams:
        """PP: the specification (read at open; ``refresh`` asks again)."""
        self.open()
        if refresh or self.params is None:
            self.params = parse_parameters(self._transact(b"PP"))
        return self.params

    def state(self) -> SensorState:
        """II: laser, motor, mode, bit rate, timer, status."""
        return parse_state(self._command(b"II", "00"))

    def laser_on(self) -> None:
        """BM: switch the laser on (already on is fine)."""
        self._command(b"BM", "00", "02")

    def laser_off(self) -> None:
        """QT: switch the laser off (and stop a stream)."""
        self._command(b"QT", "00")

    def reset(self) -> None:
        """RS: laser off, motor speed and bit rate back to default, timer reset."""
        self._command(b"RS", "00")
        self._gd_clock = ClockMapper()

    def _request(
        self,
        command: str,
        start: int | None,
        end: int | None,
        cluster: int,
        interval: int = 0,
        count: int = 0,
    ) -> ScanRequest:
        p = self.parameters()
        first = p.first_step if start is None else start
        last = p.last_step if end is None else end
        if not p.first_step <= first <= last <= p.last_step:
            raise SensorError(
                f"URG-04LX steps {first}..{last}: expected {p.first_step} <= start <= end <= {p.last_step}"
            )
        return ScanRequest(command, first, last, cluster, interval, count)

    def scan(self, start_step: int | None = None, end_step: int | None = None, cluster: int = 1) -> Scan:
        """GD: one scan (the laser is switched on first). Steps default to AMIN..AMAX."""
        request = self._request("GD", start_step, end_step, cluster)
        self.laser_on()
        reply = self._transact(request.line())
        frame = parse_scan_reply(reply, request)
        assert self.params is not None
        self.stats.scans += 1
        return scan_from_frame(frame, self.params, self._gd_clock.stamp(frame.timestamp_ms, self.clock()))

    # ------------------------------------------------------------------ streaming
    def scans(
        self,
        start_step: int | None = None,
        end_step: int | None = None,
        cluster: int = 1,
        interval: int = 0,
        count: int = 0,
    ) -> Generator[Scan, None, None]:
        """MD: scans as they come (``count`` 0: until ``stop`` or the iterator is closed), ``interval``
        scans skipped between two sent. Recovers from damaged frames, timeouts and replugs (module
        docstring); the stream is stopped (QT) when the iterator ends."""
        request = self._request("MD", start_step, end_step, cluster, interval, count)
        clock = ClockMapper()
        remaining = count
        try:
            while not self.stop.is_set():
                if self._serial is None and not self._reopen():
                    return
                try:
                    live = request if not count else replace(request, scans=remaining)
                    self._transact(live.line()).check("00")
                    for frame in self._frames(live):
                        assert self.params is not None
                        scan = scan_from_frame(
                            frame, self.params, clock.stamp(frame.timestamp_ms, self.clock())
                        )
                        self.stats.scans += 1
                        yield scan
                        if count:
                            remaining = frame.remaining
                            if remaining == 0:
                                return
                    return  # stopped
                except (SensorTimeoutError, SensorDisconnectedError, ScipError) as exc:
                    if not self.reconnect:
                        raise
                    self.stats.last_error = str(exc)
                    log.warning("%s; reconnecting", exc)
                    self._drop_port()
                    clock.restart()
        finally:
            if self._serial is not None:
                try:
                    self._transact(b"QT")
                except SensorError as exc:
                    log.debug("URG-04LX at %s: QT after the stream failed: %s", self.port, exc)

    def _frames(self, request: ScanRequest) -> Iterator[ScanFrame]:
        """Data frames of the running ``request`` until ``stop``; damaged ones dropped, and an intact
        frame that a damaged one ran into recovered."""
        prefix = request.echo_prefix()
        while not self.stop.is_set():
            block = self._read_block(time.monotonic() + self.timeout_s, "scan frame")
            try:
                reply = parse_reply(block)
                if not reply.echo.startswith(prefix):
                    log.debug("URG-04LX at %s: skipped a reply to %r", self.port, reply.echo)
                    continue
                if reply.status == "98":
                    log.info("URG-04LX at %s: laser back to normal operation (status 98)", self.port)
                    continue
                yield parse_scan_reply(reply, request)
                continue
            except ScipError as exc:
                damage = exc
            self.stats.dropped_frames += 1
            self.stats.last_error = str(damage)
            log.warning("URG-04LX at %s: dropped a damaged frame: %s", self.port, damage)
            frame = recover_scan_frame(block, request)
            if frame is not None:
                yield frame

    def _reopen(self) -> bool:
        """Reopen with exponential backoff; False if ``stop`` was set first."""
        delay, began, attempts = self.backoff_s, time.monotonic(), 0
        while not self.stop.is_set():
            attempts += 1
            try:
                self.open()
                self.stats.reconnects += 1
                log.info("URG-04LX at %s: reconnected after %d attempt(s)", self.port, attempts)
                return True
            except SensorError as exc:
                self.stats.open_failures += 1
                self.stats.last_error = str(exc)
                log.debug("URG-04LX at %s: reopen attempt %d failed: %s", self.port, attempts, exc)
            waited = time.monotonic() - began
            if self.give_up_after_s is not None and waited >= self.give_up_after_s:
                raise SensorDisconnectedError(
                    f"URG-04LX at {self.port}: not back after {attempts} attempts over {waited:.1f} s "
                    f"(last: {self.stats.last_error})"
                )
            self.stop.wait(delay)
            delay = min(2.0 * delay, self.backoff_max_s)
        return False
