"""Wheel encoders as an odometry source: the bridge's line protocol, its decoder and the serial source.

A small microcontroller (the Plat-F1's own board or an Arduino "bridge") counts the wheel encoders and
reports them over a serial port; the host turns the counts into robot poses with the project's
differential-drive odometry (:mod:`shared.odometry`, paper §2 eq. 9-11; docs/design.md §2, §3).

Wire protocol, version 1
========================
ASCII lines over a serial port (115200 8N1 by default), each ending in LF (a CR before it is ignored), at
most 128 bytes before the line ending, bytes 0x20-0x7E only. Fields are separated by one or more spaces.
Any line may end in an NMEA-style checksum ``*HH``: the XOR of every byte before the ``*``, as two hex
digits (sent upper case, either case accepted). Checksums are optional unless the host is told to require
them; bridges should send them.

Bridge to host:

``E <t_ms> <left_ticks> <right_ticks>[*HH]``
    One reading, 20 to 100 times a second, sent as soon as the two counters are latched together.
    ``t_ms`` is the bridge's clock at the latch in milliseconds, unsigned 32-bit (0..4294967295), wrapping
    to 0 (Arduino ``millis()``). ``left_ticks`` and ``right_ticks`` are the cumulative counters, signed
    32-bit (-2147483648..2147483647) wrapping two's-complement; positive means the wheel rolled forward.
    The host only uses differences, so the counters may start anywhere; fewer than 2^31 ticks and 2^31 ms
    may pass between two readings. Example: ``E 123456 -20 31*4F``.
``I <ticks_per_rev> <wheel_diameter_mm> <tread_mm> <firmware>[*HH]``
    Identity and geometry, the answer to ``?`` (a bridge may also send it unasked, e.g. after a restart).
    The numbers are positive decimals (``2000``, ``154.0``, ``1.5e3``); ``firmware`` is one token of
    printable ASCII without ``*``, at most 32 characters. Example: ``I 2000 154 330 uno-bridge-1.0*0F``.
``# <text>``
    A comment (bridge diagnostics): logged at debug level, otherwise ignored.

Host to bridge: ``?`` asks for the ``I`` line. The host sends it when it opens the port and every 0.5 s
until answered (an Arduino resets when its port is opened and needs a moment to boot).

Geometry comes from configuration (a :class:`~shared.odometry.DiffDrive`) or, if none is configured, from
the bridge's ``I`` line; when both exist, configuration wins and a disagreement is logged.

What the host does with the lines (:class:`EncoderDecoder`):

- a bad line (too long, a byte outside 0x20-0x7E, bad or missing checksum, unknown record, wrong field
  count, bad number, value out of range) is skipped, counted per reason in :class:`EncoderStats` and
  logged; nothing crashes;
- a reading whose time did not advance is skipped; one whose time went back means the bridge restarted:
  the counting restarts there (no movement is counted across the restart) and the clock is resynchronised;
- a reading that would put a wheel above ``max_wheel_speed_mps`` is skipped as implausible (a garbled line
  without checksum); three in a row are taken as a new baseline;
- host time: ``stamp = t_device + offset``, ``offset`` the running minimum of ``receive time - t_device``
  (the least-delayed line), allowed to rise by ``max_drift`` s/s for a bridge clock running slow. Stamps
  are strictly increasing and lie between the latch time and the receive time on the host clock.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from typing import Protocol, runtime_checkable

import serial  # type: ignore[import-untyped]

from robot_agent.sensors.encoder_decoder import ClockSync, EncoderDecoder, EncoderStats, OdometryReading
from robot_agent.sensors.encoder_protocol import (
    HELLO,
    MAX_LINE_BYTES,
    BridgeInfo,
    EncoderError,
    EncoderLine,
    EncoderProtocolError,
    LineSplitter,
    checksum,
    format_line,
    parse_line,
    tick_delta,
    wrap_int32,
)
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
    "OdometrySource",
    "SerialOdometry",
    "checksum",
    "format_line",
    "parse_line",
    "tick_delta",
    "wrap_int32",
]

_log = logging.getLogger(__name__)
_U32 = 1 << 32


@runtime_checkable
class OdometrySource(Protocol):
    """Where wheel odometry comes from: an iterable of :class:`OdometryReading` in increasing ``stamp_s``
    on the host clock the scans use, with the geometry it integrates with."""

    @property
    def drive(self) -> DiffDrive:
        """The robot geometry the poses are integrated with."""
        ...

    def __iter__(self) -> Iterator[OdometryReading]: ...

    def close(self) -> None:
        """Release the device (idempotent)."""
        ...


def _same_geometry(a: DiffDrive, b: DiffDrive) -> bool:
    return all(
        math.isclose(getattr(a, name), getattr(b, name), rel_tol=1e-9)
        for name in ("wheel_diameter_m", "tread_m", "ticks_per_turn")
    )


_HELLO_EVERY_S = 0.5


class SerialOdometry:
    """Wheel odometry from an encoder bridge on a serial port (any pyserial URL: ``/dev/ttyACM0``,
    ``rfc2217://host:port``, ...). See the module docstring for the protocol.

    :meth:`open` (or ``with``, or the first iteration) opens the port, asks ``?`` and, if no ``drive`` is
    configured, waits up to ``hello_timeout_s`` for the ``I`` line. A reader thread then stamps each chunk
    on arrival with ``clock`` (default :func:`time.time`, as the URG-04LX driver's: scans and odometry must
    be stamped on the same clock for :mod:`~robot_agent.sensors.pairing`), decodes it and buffers up to
    ``max_buffered`` readings (the oldest are dropped and counted if the consumer falls behind; the pose
    integration never misses a line). Iterating (one consumer) yields the readings; it raises
    :class:`EncoderError` if none arrives for ``stall_timeout_s`` or the port fails, and ends after
    :meth:`close`. O(1) per line.
    """

    def __init__(
        self,
        port: str,
        *,
        drive: DiffDrive | None = None,
        baudrate: int = 115200,
        origin: Pose2D | None = None,
        require_checksum: bool | None = None,
        hello_timeout_s: float = 3.0,
        stall_timeout_s: float | None = 2.0,
        max_buffered: int = 10_000,
        max_wheel_speed_mps: float | None = 5.0,
        clock: Callable[[], float] = time.time,
    ) -> None:
        self.port = port
        self.baudrate = baudrate
        self.hello_timeout_s = hello_timeout_s
        self.stall_timeout_s = stall_timeout_s
        self._configured = drive
        self._origin = origin
        self._require_checksum = require_checksum
        self._max_speed = max_wheel_speed_mps
        self._clock = clock
        self._queue: deque[OdometryReading] = deque(maxlen=max_buffered)
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._error: EncoderError | None = None
        self._done = False
        self._serial: serial.SerialBase | None = None
        self._thread: threading.Thread | None = None
        self._decoder: EncoderDecoder | None = None
        self._splitter = LineSplitter()
        self._early_stats = EncoderStats()

    @property
    def drive(self) -> DiffDrive:
        """The geometry in use: the configured one, else the bridge's (known once open)."""
        if self._decoder is not None:
            return self._decoder.drive
        if self._configured is not None:
            return self._configured
        raise EncoderError(f"encoder port {self.port}: the robot geometry is unknown until the port is open")

    @property
    def stats(self) -> EncoderStats:
        """Counters of the lines seen so far (see :class:`EncoderStats`)."""
        return self._decoder.stats if self._decoder is not None else self._early_stats

    def open(self) -> SerialOdometry:
        """Open the port, greet the bridge, start the reader thread. Idempotent."""
        if self._serial is not None:
            return self
        try:
            port = serial.serial_for_url(self.port, baudrate=self.baudrate, timeout=0.1, write_timeout=1.0)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise EncoderError(f"encoder port {self.port}: cannot open it ({exc})") from None
        try:
            early, info = self._greet(port)
        except (serial.SerialException, OSError) as exc:
            port.close()
            raise EncoderError(f"encoder port {self.port}: {exc}") from None
        except EncoderError:
            port.close()
            raise
        self._serial = port
        drive = self._configured
        if drive is None:
            assert info is not None  # _greet waits for it
            drive = info.to_drive()
        decoder = EncoderDecoder(
            drive,
            origin=self._origin,
            require_checksum=self._require_checksum,
            max_wheel_speed_mps=self._max_speed,
        )
        decoder.stats = self._early_stats
        self._decoder = decoder
        for line, rx in early:
            self._handle(line, rx)
        self._thread = threading.Thread(target=self._run, name=f"encoders {self.port}", daemon=True)
        self._thread.start()
        return self

    def _greet(self, port: serial.SerialBase) -> tuple[list[tuple[bytes, float]], BridgeInfo | None]:
        """Send ``?``; if no geometry is configured, read until the ``I`` line (``E`` lines are kept)."""
        early: list[tuple[bytes, float]] = []
        port.write(HELLO)
        if self._configured is not None:
            return early, None
        info: BridgeInfo | None = None
        deadline = time.monotonic() + self.hello_timeout_s
        next_hello = time.monotonic() + _HELLO_EVERY_S
        while (now := time.monotonic()) < deadline:
            if now >= next_hello:
                port.write(HELLO)
                next_hello = now + _HELLO_EVERY_S
            data = port.read(max(1, port.in_waiting))
            rx = self._clock()
            for line in self._splitter.feed(data):
                try:
                    record = parse_line(line)
                except EncoderProtocolError:
                    record = None
                if info is None and isinstance(record, BridgeInfo):
                    _log.info("encoder bridge on %s: %s", self.port, record)
                    info = record
                early.append((line, rx))  # decoded (and counted) once the geometry is known
            if info is not None:
                return early, info
        raise EncoderError(
            f"encoder port {self.port}: the bridge did not answer '?' with an 'I <ticks_per_rev> "
            f"<wheel_diameter_mm> <tread_mm> <firmware>' line within {self.hello_timeout_s} s; "
            "configure the robot geometry or check the bridge"
        )

    def _handle(self, line: bytes, rx: float) -> None:
        assert self._decoder is not None
        out = self._decoder.feed_line(line, rx)
        if isinstance(out, BridgeInfo) and not _same_geometry(out.to_drive(), self._decoder.drive):
            _log.warning("encoder bridge reports %s; using the configured %s", out, self._decoder.drive)
        elif isinstance(out, OdometryReading):
            with self._cond:
                if len(self._queue) == self._queue.maxlen:
                    self._decoder.stats.dropped += 1
                self._queue.append(out)
                self._cond.notify_all()

    def _run(self) -> None:
        port = self._serial
        assert port is not None
        try:
            while not self._stop.is_set():
                data = port.read(max(1, port.in_waiting))
                if data:
                    rx = self._clock()
                    for line in self._splitter.feed(data):
                        self._handle(line, rx)
        except (serial.SerialException, OSError) as exc:
            if not self._stop.is_set():
                self._error = EncoderError(f"encoder port {self.port}: {exc} (bridge unplugged?)")
                _log.error("%s", self._error)
        finally:
            with self._cond:
                self._done = True
                self._cond.notify_all()

    def __iter__(self) -> Iterator[OdometryReading]:
        self.open()
        while True:
            with self._cond:
                ready = self._cond.wait_for(lambda: bool(self._queue) or self._done, self.stall_timeout_s)
                if not ready:
                    raise EncoderError(
                        f"encoder port {self.port}: no reading for {self.stall_timeout_s} s "
                        f"({self.stats.malformed} bad lines); is the bridge running?"
                    )
                if self._queue:
                    item = self._queue.popleft()
                elif self._error is not None:
                    raise self._error
                else:
                    return
            yield item

    def close(self) -> None:
        """Stop the reader thread and close the port; iterations end after the buffered readings."""
        self._stop.set()
        if self._serial is not None and hasattr(self._serial, "cancel_read"):
            self._serial.cancel_read()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        self._close_port()
        with self._cond:
            self._done = True
            self._cond.notify_all()

    def _close_port(self) -> None:
        if self._serial is not None:
            try:
                self._serial.close()
            except (serial.SerialException, OSError) as exc:
                _log.debug("closing encoder port %s: %s", self.port, exc)

    def __enter__(self) -> SerialOdometry:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()
