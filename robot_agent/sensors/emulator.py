"""A Hokuyo URG-04LX on a pseudo-terminal: answers SCIP 2.0 in a background thread, for tests and demos.

``UrgEmulator(scans, link=PATH)`` opens a pty pair (``os.openpty``) and points the symlink ``PATH`` (which
it owns; a temporary one if not given) at the slave's ``/dev/pts/N``; a driver opens ``PATH`` as it would
``/dev/ttyACM0``. The sensor's behaviour (commands, scans to frames, SCIP 1.1 boot, frame faults) is
:class:`~robot_agent.sensors.urg_model.UrgModel`; this module adds the pty, the pace and the unplug.

Pace: ``rate_hz=None`` sends the next frame once the previous one has been read from the pty (the reader
sets the pace; nothing is lost), else frames at ``rate_hz`` (while the last frame is still being written,
the next scan is skipped, as a sensor with a full buffer would). ``unplug`` (:meth:`unplug`, or
``schedule={frame_no: "unplug"}``: before that frame) waits until the frame in flight has been read (one
never read is sent again later), removes the symlink and closes the pty, so reads on it fail; after
``replug_after_s`` or on :meth:`replug` a new pty appears behind the same symlink, the sensor booting
afresh (SCIP 1.1 again if so configured, laser off, timer at 0).

``python -m robot_agent.sensors.emulator --world sim --link /tmp/ttyURG`` runs one standalone.
"""

from __future__ import annotations

import contextlib
import fcntl
import logging
import os
import queue
import select
import struct
import termios
import threading
import time
import tty
from collections.abc import Iterable, Mapping
from pathlib import Path

from robot_agent.sensors.errors import SensorError
from robot_agent.sensors.scip_info import URG04LX_PARAMS, SensorParams
from robot_agent.sensors.urg_model import FAULTS, AtEnd, EmulatorFrame, Fault, UrgModel
from shared.stopsignals import stop_on_signals
from shared.types import Scan

__all__ = ["UrgEmulator", "main"]

log = logging.getLogger(__name__)

_POLL_S = 0.002  # how often a reader-paced stream looks whether the last frame has been read
_IDLE_S = 0.02


class UrgEmulator:
    """See the module docstring. Use as a context manager or start()/stop()."""

    def __init__(
        self,
        scans: Iterable[Scan],
        *,
        link: str | Path | None = None,
        rate_hz: float | None = None,
        scip1_boot: bool = False,
        params: SensorParams = URG04LX_PARAMS,
        no_return_code: int = 0,
        start_time_ms: int = 0,
        schedule: Mapping[int, Fault] | None = None,
        replug_after_s: float | None = 0.2,
        at_end: AtEnd = "stop",
    ) -> None:
        if rate_hz is not None and not rate_hz > 0:
            raise SensorError(f"emulator rate_hz = {rate_hz!r}: expected a positive rate or None")
        self.model = UrgModel(
            scans,
            scip1_boot=scip1_boot,
            params=params,
            no_return_code=no_return_code,
            start_time_ms=start_time_ms,
            schedule=schedule,
            at_end=at_end,
            fixed_step_s=None if rate_hz is None else 1.0 / rate_hz,
        )
        self._tmpdir: Path | None = None
        if link is None:
            import tempfile

            self._tmpdir = Path(tempfile.mkdtemp(prefix="urg-emulator-"))
            link = self._tmpdir / "ttyURG"
        self.link = Path(link)
        self.rate_hz = rate_hz
        self.replug_after_s = replug_after_s
        self.plugs = 0
        self._control: queue.Queue[tuple[str, float | None, threading.Event]] = queue.Queue()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._master: int | None = None
        self._slave: int | None = None
        self._replug_at: float | None = None
        self._out = bytearray()
        self._inbuf = bytearray()
        self._pending = False  # a frame written but not yet read by the other side
        self._next_due = time.monotonic()

    # ------------------------------------------------------------------ what it did
    @property
    def path(self) -> str:
        """The stable device path to give the driver (the symlink)."""
        return str(self.link)

    @property
    def tty_name(self) -> str | None:
        """The current pty slave (``/dev/pts/N``), None while unplugged."""
        return os.ttyname(self._slave) if self._slave is not None else None

    @property
    def frames(self) -> list[EmulatorFrame]:
        """Every scan frame produced, in order."""
        return self.model.frames

    @property
    def commands(self) -> list[bytes]:
        """Every command line received, in order."""
        return self.model.commands

    def delivered(self) -> list[int]:
        """Scan indices of the intact frames sent so far, in order."""
        return self.model.delivered()

    # ------------------------------------------------------------------ lifecycle
    def __enter__(self) -> UrgEmulator:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def start(self) -> None:
        """Plug in and answer in a background thread."""
        if self._thread is None:
            self._plug(first=True)
            self._thread = threading.Thread(target=self._run, name="urg-emulator", daemon=True)
            self._thread.start()

    def stop(self) -> None:
        """Stop the thread, close the pty, remove the symlink (and its temporary folder)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)
            self._thread = None
        self._unplug_now(wait_read=False)
        if self._tmpdir is not None:
            import shutil

            shutil.rmtree(self._tmpdir, ignore_errors=True)

    # ------------------------------------------------------------------ faults
    def inject(self, fault: Fault) -> None:
        """Apply ``fault`` to the next frame; ``unplug`` unplugs now (see :meth:`unplug`)."""
        if fault not in FAULTS:
            raise SensorError(f"emulator fault {fault!r}: expected one of {', '.join(FAULTS)}")
        if fault == "unplug":
            self.unplug()
        else:
            self.model.inject(fault)

    def unplug(self, replug_after_s: float | None = None) -> None:
        """Unplug (see the module docstring); replug after ``replug_after_s`` if given, else on
        :meth:`replug`. Returns when done."""
        self._call("unplug", replug_after_s)

    def replug(self) -> None:
        """Plug a fresh pty in behind the same symlink. Returns when done."""
        self._call("replug", None)

    def _call(self, what: str, arg: float | None, timeout_s: float = 30.0) -> None:
        if self._thread is None:
            raise SensorError(f"emulator: {what} needs a started emulator")
        done = threading.Event()
        self._control.put((what, arg, done))
        if not done.wait(timeout_s):
            raise SensorError(f"emulator: {what} did not happen within {timeout_s} s")

    # ------------------------------------------------------------------ pty
    def _plug(self, first: bool = False) -> None:
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no line editing, before anyone opens it
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        tmp = self.link.with_name(self.link.name + ".new")
        tmp.unlink(missing_ok=True)
        os.symlink(os.ttyname(slave), tmp)
        os.replace(tmp, self.link)
        self.plugs += 1
        if not first:
            self.model.power_on()
        self._out.clear()
        self._inbuf.clear()
        self._pending = False
        log.info("URG-04LX emulator plugged in at %s -> %s", self.link, os.ttyname(slave))

    def _unplug_now(self, replug_after_s: float | None = None, wait_read: bool = True) -> None:
        self._replug_at = None if replug_after_s is None else time.monotonic() + replug_after_s
        if self._master is None:
            return
        if wait_read:
            self._flush()
        if self._pending:
            self.model.requeue_last()
        self.link.unlink(missing_ok=True)
        for fd in (self._master, self._slave):
            if fd is not None:
                os.close(fd)
        self._master = self._slave = None
        log.info("URG-04LX emulator unplugged from %s", self.link)

    def _unread(self) -> int:
        if self._slave is None:
            return 0
        raw = fcntl.ioctl(self._slave, termios.FIONREAD, b"\0\0\0\0")
        return int(struct.unpack("i", raw)[0])

    def _flush(self, bound_s: float = 10.0, settle_s: float = 0.05) -> None:
        """Write what is queued and wait (bounded) until the reader has taken it: the pty's input queue
        must stay empty for ``settle_s`` (bytes still on their way into it do not show at once)."""
        end, quiet_since = time.monotonic() + bound_s, None
        while time.monotonic() < end:
            if self._out or self._unread():
                quiet_since = None
            elif quiet_since is None:
                quiet_since = time.monotonic()
            elif time.monotonic() - quiet_since >= settle_s:
                break
            self._io_step(_POLL_S)
        self._pending = bool(self._out or self._unread())

    # ------------------------------------------------------------------ the loop
    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                self._control_step()
                if self._master is not None:
                    self._io_step()
                    self._stream_step()
                elif self._replug_at is not None and time.monotonic() >= self._replug_at:
                    self._plug()
                else:
                    self._stop.wait(_IDLE_S)
        except Exception:  # the thread must not die silently
            log.exception("URG-04LX emulator failed")
            raise

    def _control_step(self) -> None:
        while True:
            try:
                what, arg, done = self._control.get_nowait()
            except queue.Empty:
                return
            if what == "unplug":
                self._unplug_now(arg)
            elif self._master is None:  # replug
                self._plug()
            done.set()

    def _poll_s(self) -> float:
        if self.model.stream is None:
            return _IDLE_S
        if self.rate_hz is None:
            return _POLL_S
        return min(_IDLE_S, max(self._next_due - time.monotonic(), 0.0))

    def _io_step(self, poll_s: float | None = None) -> None:
        assert self._master is not None
        writers = [self._master] if self._out else []
        wait = self._poll_s() if poll_s is None else poll_s
        readable, writable, _ = select.select([self._master], writers, [], wait)
        if readable:
            with contextlib.suppress(BlockingIOError, InterruptedError):
                self._inbuf += os.read(self._master, 4096)
            self._handle_lines()
        if writable and self._out:
            with contextlib.suppress(BlockingIOError, InterruptedError):
                del self._out[: os.write(self._master, self._out)]
        if self._pending and not self._out and self._unread() == 0:
            self._pending = False

    def _handle_lines(self) -> None:
        while True:
            ends = [i for i in (self._inbuf.find(b"\n"), self._inbuf.find(b"\r")) if i >= 0]
            if not ends:
                return
            line = bytes(self._inbuf[: min(ends)])
            del self._inbuf[: min(ends) + 1]
            if line:
                was_streaming = self.model.stream is not None
                self._out += self.model.answer(line)
                if self.model.stream is not None and not was_streaming:
                    self._next_due = time.monotonic()

    def _stream_step(self) -> None:
        if self.model.stream is None:
            return
        if self.rate_hz is None:
            if self._pending or self._out:
                return
        else:
            now = time.monotonic()
            if now < self._next_due:
                return
            self._next_due = max(self._next_due + 1.0 / self.rate_hz, now - 1.0 / self.rate_hz)
            if self._out:  # the reader is behind: this scan is lost
                self.model.take()
                return
        if self.model.unplug_due():
            self._unplug_now(self.replug_after_s or 0.0)
            return
        frame = self.model.next_frame()
        if frame is not None:
            self._out += frame
            self._pending = True


def main(argv: list[str] | None = None) -> int:
    """``python -m robot_agent.sensors.emulator --world sim|sim:FILE|LOG --link PATH``: an emulated
    URG-04LX until Ctrl-C."""
    import argparse
    import itertools

    from robot_agent.sources import open_scans
    from shared.errors import LinemapError

    ap = argparse.ArgumentParser(prog="python -m robot_agent.sensors.emulator", description=main.__doc__)
    ap.add_argument("--world", default="sim", help="sim | sim:WORLD_FILE | a laser log (default: sim)")
    ap.add_argument("--link", required=True, help="symlink to create for the device, e.g. /tmp/ttyURG")
    ap.add_argument("--rate", type=float, default=10.0, help="scans per second (0: as fast as they are read)")
    ap.add_argument("--scip1", action="store_true", help="boot in SCIP 1.1 (the driver must switch it)")
    ap.add_argument(
        "--at-end", choices=["stop", "hold", "loop"], default="loop", help="when the scans run out"
    )
    ap.add_argument("--seed", type=int, default=0, help="simulator seed")
    args = ap.parse_args(argv)
    if args.world.startswith("urg:"):
        print("emulator: --world must be 'sim', 'sim:WORLD_FILE' or a log, not a device")
        return 2
    stop = threading.Event()
    stop_on_signals(stop)
    try:
        scans = open_scans(args.world, seed=args.seed)
        first = next(scans)  # a bad world fails here, before the device appears
        emulator = UrgEmulator(
            itertools.chain([first], scans),
            link=args.link,
            rate_hz=args.rate or None,
            scip1_boot=args.scip1,
            at_end=args.at_end,
        )
        with emulator:
            print(f"URG-04LX emulator: {emulator.path} -> {emulator.tty_name} ({args.world}); Ctrl-C stops")
            stop.wait()
    except StopIteration:
        print(f"emulator: {args.world} has no scans")
        return 2
    except (LinemapError, OSError) as exc:
        print(f"emulator: {exc}")
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
