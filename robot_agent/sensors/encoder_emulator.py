"""The simulated robot's encoder bridge: an odometry source backed by :mod:`shared.sim`, and an emulator
that speaks the bridge protocol (:mod:`robot_agent.sensors.encoders`) on a real pseudo-terminal.

:class:`SimOdometry` turns a :class:`~shared.sim.SimRun`'s cumulative encoder ticks into the ``E`` lines a
bridge would send (32-bit counters and millisecond clock, wrapping, from any starting value) and decodes
them with the same :class:`~robot_agent.sensors.encoder_protocol.EncoderDecoder` as the serial source, as a
host with no transport delay would. Between two scans the tick increment is spread evenly over
``substeps`` readings: for the simulator's constant-curvature steps (straight legs, turns in place)
the wheel travel grows linearly along the step (eq. 9-11 inverted, see
:func:`~shared.sim.wheel_displacements_between`), so this samples the same motion at the bridge's rate.

:class:`BridgeEmulator` writes such lines (or any bytes, garbage included) to the master side of a
pseudo-terminal from a thread and answers every ``?`` with its ``I`` line, so :class:`SerialOdometry` can be
run against it with a real tty between them.
"""

from __future__ import annotations

import logging
import os
import select
import threading
import time
import tty
from collections.abc import Iterator, Sequence

from robot_agent.sensors.encoder_decoder import EncoderDecoder, OdometryReading
from robot_agent.sensors.encoder_protocol import (
    HELLO,
    BridgeInfo,
    EncoderLine,
    LineSplitter,
    format_line,
    wrap_int32,
)
from shared.errors import InvalidInputError
from shared.odometry import DiffDrive
from shared.sim import SimRun
from shared.types import Pose2D

__all__ = ["BridgeEmulator", "SimOdometry", "open_pty"]

_log = logging.getLogger(__name__)
_U32 = 1 << 32


class SimOdometry:
    """Wheel odometry of a simulated run, as the serial source would decode it from a bridge.

    Readings come at the scans' times (``substeps = 1``: exactly ``run.ticks`` and ``run.odometry_poses``)
    or ``substeps`` times as often. ``device_epoch_ms`` and ``tick_origin`` are the bridge's clock and
    counters at the first reading (to exercise the 32-bit wrap); ``origin`` is the first pose (default: the
    run's first odometry pose). Host stamps are the scans' clock. O(1) per reading.
    """

    def __init__(
        self,
        run: SimRun,
        *,
        substeps: int = 1,
        device_epoch_ms: int = 0,
        tick_origin: tuple[int, int] = (0, 0),
        origin: Pose2D | None = None,
        firmware: str = "linemap-sim-1",
    ) -> None:
        if (
            isinstance(substeps, bool)
            or not isinstance(substeps, int)
            or substeps < 1
            or run.rate_hz * substeps > 1000.0
        ):
            raise InvalidInputError(
                f"SimOdometry substeps = {substeps!r}: expected an integer >= 1 with at most 1000 readings/s "
                f"(the run has {run.rate_hz} scans/s)"
            )
        self.run = run
        self.substeps = substeps
        self.device_epoch_ms = int(device_epoch_ms)
        self.tick_origin = (int(tick_origin[0]), int(tick_origin[1]))
        self.origin = origin if origin is not None else run.odometry_poses[0]
        self.firmware = firmware

    @property
    def drive(self) -> DiffDrive:
        """The simulated robot's geometry."""
        return self.run.drive

    @property
    def info(self) -> BridgeInfo:
        """The ``I`` line this bridge answers ``?`` with."""
        d = self.run.drive
        return BridgeInfo(d.ticks_per_turn, d.wheel_diameter_m * 1000.0, d.tread_m * 1000.0, self.firmware)

    def records(self) -> Iterator[tuple[float, EncoderLine]]:
        """``(host time s, E record)`` of every reading, in order (zero transport delay)."""
        stamps = [s.stamp_s for s in self.run.scans]
        ticks = self.run.ticks.tolist()
        m = self.substeps
        start_ms = round(stamps[0] * 1000.0)
        for i, (left, right) in enumerate(ticks):
            subs = [(0, 0, stamps[i])] if i == 0 else []
            if i > 0:
                d_left, d_right = left - ticks[i - 1][0], right - ticks[i - 1][1]
                span = stamps[i] - stamps[i - 1]
                for k in range(1, m + 1):
                    # round-half-up share of the step's increment; k = m gives the step's end exactly
                    subs.append(
                        (
                            (2 * d_left * k + m) // (2 * m) - d_left,
                            (2 * d_right * k + m) // (2 * m) - d_right,
                            stamps[i] if k == m else stamps[i - 1] + span * k / m,
                        )
                    )
            for off_left, off_right, stamp in subs:
                device = round(stamp * 1000.0) - start_ms
                host = stamps[0] + device / 1000.0
                yield (
                    host,
                    EncoderLine(
                        (self.device_epoch_ms + device) % _U32,
                        wrap_int32(self.tick_origin[0] + left + off_left),
                        wrap_int32(self.tick_origin[1] + right + off_right),
                    ),
                )

    def lines(self, *, with_checksum: bool = True) -> list[bytes]:
        """The bytes the bridge sends for the run, one ``E`` line per reading."""
        return [format_line(rec, with_checksum=with_checksum) for _, rec in self.records()]

    def __iter__(self) -> Iterator[OdometryReading]:
        decoder = EncoderDecoder(self.run.drive, origin=self.origin)
        for host_s, record in self.records():
            reading = decoder.feed(record, host_s)
            if reading is not None:
                yield reading

    def close(self) -> None:
        """Nothing to release."""


def open_pty() -> tuple[int, int, str]:
    """A pseudo-terminal in raw mode (no echo, no CR/LF translation, no flow control): ``(master_fd,
    slave_fd, slave_path)``. The caller closes both descriptors."""
    master, slave = os.openpty()
    tty.setraw(slave)
    return master, slave, os.ttyname(slave)


class BridgeEmulator:
    """An encoder bridge on the master side of a pseudo-terminal, run in a thread.

    It writes ``lines`` (bytes, sent as given) in order, as fast as the other side reads them (or one per
    ``pace_s`` seconds), and answers each ``?`` line with ``info`` (after ignoring the first
    ``ignore_hellos``, like a bridge still booting). With ``wait_for_hello`` it sends nothing before the
    first answered ``?``. ``timeout_s`` is a safety limit: blocked that long, it gives up (``error``).
    """

    def __init__(
        self,
        master_fd: int,
        lines: Sequence[bytes],
        *,
        info: BridgeInfo | None = None,
        wait_for_hello: bool = False,
        ignore_hellos: int = 0,
        pace_s: float | None = None,
        timeout_s: float = 30.0,
    ) -> None:
        self.fd = master_fd
        self.lines = list(lines)
        self.info = info
        self.wait_for_hello = wait_for_hello
        self.ignore_hellos = ignore_hellos
        self.pace_s = pace_s
        self.timeout_s = timeout_s
        self.hellos = 0
        self.written = 0
        self.error: BaseException | None = None
        self.done = threading.Event()
        self._stop = threading.Event()
        self._splitter = LineSplitter()
        self._thread = threading.Thread(target=self._run, name="encoder bridge emulator", daemon=True)

    def start(self) -> BridgeEmulator:
        """Start the thread."""
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop the thread (it stops between two lines) and wait for it."""
        self._stop.set()
        self._thread.join(timeout=self.timeout_s)

    def __enter__(self) -> BridgeEmulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _run(self) -> None:
        try:
            os.set_blocking(self.fd, False)
            deadline = time.monotonic() + self.timeout_s
            while self.wait_for_hello and self.hellos <= self.ignore_hellos:
                self._wait(read=True, deadline=deadline)
                self._answer_hellos()
            for line in self.lines:
                self._write(line)
                self.written += 1
                self._answer_hellos()
                if self.pace_s is not None and self._stop.wait(self.pace_s):
                    return
            self.done.set()
        except (OSError, TimeoutError) as exc:
            if not self._stop.is_set():
                self.error = exc
                _log.warning("encoder bridge emulator stopped: %s", exc)

    def _wait(self, *, read: bool, deadline: float) -> None:
        while not self._stop.is_set():
            if time.monotonic() > deadline:
                raise TimeoutError(f"emulator blocked for {self.timeout_s} s")
            r, w, _ = select.select([self.fd] if read else [], [] if read else [self.fd], [], 0.1)
            if r or w:
                return
        raise InterruptedError("stopped")

    def _write(self, data: bytes) -> None:
        deadline = time.monotonic() + self.timeout_s
        view = memoryview(data)
        while view:
            self._wait(read=False, deadline=deadline)
            try:
                view = view[os.write(self.fd, view) :]
            except BlockingIOError:
                continue

    def _answer_hellos(self) -> None:
        try:
            data = os.read(self.fd, 4096)
        except BlockingIOError:
            return
        for line in self._splitter.feed(data):
            if line.strip() != HELLO.strip():
                continue
            self.hellos += 1
            if self.info is not None and self.hellos > self.ignore_hellos:
                self._write(format_line(self.info))
