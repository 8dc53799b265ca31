"""The emulated URG-04LX's behaviour without I/O: command lines in, reply bytes out, scans to frames.

:class:`UrgModel` is what :class:`~robot_agent.sensors.emulator.UrgEmulator` runs behind its pty. Each
scan frame (MD/MS stream or GD/GS) takes the next :class:`~shared.types.Scan` from ``scans``, sampled at
the sensor's steps (PP: AMIN..AMAX of ARES, front AFRT) and rounded to mm; no return becomes the error
code ``no_return_code``; a cluster reports its smallest valid range (as the real sensor does). The timer
(24-bit ms, wraps) advances by the scans' own stamp steps (or ``fixed_step_s``). ``scip1_boot`` starts it
in SCIP 1.1: it answers only ``SCIP2.0`` (refusing the rest) until switched. Faults for a frame
(``checksum``: one data line's checksum garbled; ``truncate``: the frame cut in half) come from
:meth:`inject` or ``schedule`` (frame number to fault). All steps are O(reply size).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from robot_agent.sensors.errors import SensorError
from robot_agent.sensors.scip import ERROR_CODE_LIMIT_MM, SWITCH_COMMAND, TIMESTAMP_MODULUS, encode_reply
from robot_agent.sensors.scip_info import URG04LX_PARAMS, SensorParams, encode_info_reply
from robot_agent.sensors.scip_scan import ScanRequest, encode_scan_reply, parse_scan_command
from shared.types import IntArray, Scan

__all__ = ["FAULTS", "EmulatorFrame", "Fault", "UrgModel", "cluster_values", "sample_steps_mm"]

Fault = Literal["checksum", "truncate", "unplug"]
FAULTS: tuple[Fault, ...] = ("checksum", "truncate", "unplug")
AtEnd = Literal["stop", "hold", "loop"]
_NON_MEASURABLE = 19  # error code of a step outside AMIN..AMAX
_VERSIONS = [
    ("VEND", "Hokuyo Automatic Co.,Ltd."),
    ("PROD", "SOKUIKI Sensor URG-04LX"),
    ("FIRM", "3.3.00(linemap emulator)"),
    ("PROT", "SCIP 2.0"),
    ("SERI", "H0000000"),
]


def sample_steps_mm(scan: Scan, params: SensorParams, no_return_code: int = 0) -> IntArray:
    """Range (mm) at every step 0..ARES-1 of a sensor with ``params`` looking at ``scan``: the beam nearest
    each step's angle, rounded to mm; outside the range window or NaN: ``no_return_code``; outside
    AMIN..AMAX: 19 (non-measurable). O(steps)."""
    steps = np.arange(params.steps_per_turn)
    angles = (steps - params.front_step) * params.angle_increment_rad
    idx = np.rint((angles - scan.angle_min_rad) / scan.angle_increment_rad).astype(np.int64)
    inside = (idx >= 0) & (idx < scan.beam_count)
    ranges = np.where(inside, scan.ranges_m[np.clip(idx, 0, max(scan.beam_count - 1, 0))], np.nan)
    with np.errstate(invalid="ignore"):
        mm = np.where(np.isfinite(ranges), np.rint(ranges * 1000.0), -1.0)
    ok = (mm >= max(params.min_range_mm, ERROR_CODE_LIMIT_MM)) & (mm <= params.max_range_mm)
    out = np.where(ok, mm, no_return_code).astype(np.int64)
    out[(steps < params.first_step) | (steps > params.last_step)] = _NON_MEASURABLE
    return out


def cluster_values(step_mm: IntArray, request: ScanRequest) -> IntArray:
    """The values of ``request``: per cluster the smallest valid range, else the first step's error code."""
    vals = step_mm[request.start_step : request.end_step + 1]
    g = request.group
    grid = np.concatenate([vals, np.full((-vals.size) % g, -1)]).reshape(-1, g)
    valid = grid >= ERROR_CODE_LIMIT_MM
    best = np.where(valid, grid, np.iinfo(np.int64).max).min(axis=1)
    return np.where(valid.any(axis=1), best, grid[:, 0]).astype(np.int64)


@dataclass(frozen=True, slots=True)
class EmulatorFrame:
    """A scan frame produced: its number, the index of the scan it carries (in the order taken from
    ``scans``), its time stamp and the fault applied: None (intact), ``checksum``, ``truncate``, or
    ``unread`` (unplugged before the reader took it: that scan is sent again after the replug)."""

    frame_no: int
    scan_index: int
    fault: str | None
    timestamp_ms: int


class UrgModel:
    """A URG-04LX's protocol state and scans (see the module docstring)."""

    def __init__(
        self,
        scans: Iterable[Scan],
        *,
        scip1_boot: bool = False,
        params: SensorParams = URG04LX_PARAMS,
        no_return_code: int = 0,
        start_time_ms: int = 0,
        schedule: Mapping[int, Fault] | None = None,
        at_end: AtEnd = "stop",
        fixed_step_s: float | None = None,
    ) -> None:
        if not 0 <= no_return_code < ERROR_CODE_LIMIT_MM:
            raise SensorError(f"emulator no_return_code = {no_return_code}: expected an error code 0..19")
        for k, fault in (schedule or {}).items():
            if fault not in FAULTS:
                raise SensorError(f"emulator schedule[{k}] = {fault!r}: expected one of {', '.join(FAULTS)}")
        if at_end not in ("stop", "hold", "loop"):
            raise SensorError(f"emulator at_end = {at_end!r}: expected 'stop', 'hold' or 'loop'")
        self.scip1_boot = scip1_boot
        self.params = params
        self.no_return_code = no_return_code
        self.schedule: dict[int, Fault] = dict(schedule or {})
        self.at_end = at_end
        self.fixed_step_s = fixed_step_s
        self.frames: list[EmulatorFrame] = []
        self.commands: list[bytes] = []
        self.exhausted = False
        self.timer_ms = float(start_time_ms)
        self._scans: Iterator[Scan] = iter(scans)
        self._seen: list[Scan] = []
        self._taken = 0
        self._requeued: deque[tuple[int, Scan]] = deque()
        self._last: tuple[int, Scan] | None = None
        self._faults: deque[Fault] = deque()
        self.power_on(reset_timer=False)

    def power_on(self, reset_timer: bool = True) -> None:
        """A (re)boot: SCIP mode as configured, laser off, no stream; the timer restarts at 0."""
        self.scip2 = not self.scip1_boot
        self.laser = False
        self.stream: ScanRequest | None = None
        self._left = 0
        if reset_timer:
            self.timer_ms = 0.0

    # ------------------------------------------------------------------ faults
    def inject(self, fault: Fault) -> None:
        """Garble (``checksum``) or cut (``truncate``) the next frame."""
        if fault not in ("checksum", "truncate"):
            raise SensorError(f"emulator frame fault {fault!r}: expected 'checksum' or 'truncate'")
        self._faults.append(fault)

    def unplug_due(self) -> bool:
        """Whether ``schedule`` unplugs before the next frame (the entry is used up)."""
        if self.schedule.get(len(self.frames)) == "unplug":
            del self.schedule[len(self.frames)]
            return True
        return False

    def requeue_last(self) -> None:
        """The last frame never reached the reader: mark it ``unread`` and send its scan again next."""
        if self._last is not None and self.frames:
            self._requeued.appendleft(self._last)
            self.frames[-1] = replace(self.frames[-1], fault="unread")

    def delivered(self) -> list[int]:
        """Scan indices of the intact frames produced so far, in order."""
        return [f.scan_index for f in self.frames if f.fault is None]

    # ------------------------------------------------------------------ scans
    def take(self) -> tuple[int, Scan] | None:
        """The next scan and its index (also to skip one), None when the scans ran out (``at_end``)."""
        if self._requeued:
            return self._requeued.popleft()
        try:
            scan = next(self._scans)
        except StopIteration:
            self.exhausted = True
            if self.at_end == "hold" and self._last is not None:
                return self._last
            if self.at_end == "loop" and self._seen:
                self._scans, self._seen = iter(list(self._seen)), []
                return self.take()
            return None
        if self.at_end == "loop":
            self._seen.append(scan)
        self._taken += 1
        return self._taken - 1, scan

    def next_frame(self) -> bytes | None:
        """The stream's next frame (None: no stream, or no scans left); after it, ``interval`` scans are
        skipped, and after the last of ``scans`` frames the stream ends and the laser goes off."""
        request = self.stream
        if request is None:
            return None
        if request.scans:
            self._left -= 1
        frame = self._frame(request, remaining=self._left if request.scans else 0)
        if frame is None:
            self.stream = None
            return None
        for _ in range(request.interval):
            self.take()
        if request.scans and self._left == 0:
            self.stream, self.laser = None, False
        return frame

    def _frame(self, request: ScanRequest, remaining: int) -> bytes | None:
        taken = self.take()
        if taken is None:
            return None
        index, scan = taken
        if self._last is not None:
            step_s = scan.stamp_s - self._last[1].stamp_s
            if self.fixed_step_s is not None or not 0.0 < step_s < 10.0:
                step_s = self.fixed_step_s or 60.0 / self.params.scan_rpm
            self.timer_ms += step_s * 1000.0
        self._last = taken
        stamp = round(self.timer_ms) % TIMESTAMP_MODULUS
        values = cluster_values(sample_steps_mm(scan, self.params, self.no_return_code), request)
        if request.chars == 2:  # 12 bits: farther is no return
            values = np.where(values < 1 << 12, values, self.no_return_code)
        frame = encode_scan_reply(request, stamp, values, remaining=remaining)
        fault = self._faults.popleft() if self._faults else self.schedule.pop(len(self.frames), None)
        if fault == "checksum":
            lines = frame.split(b"\n")
            n = 3 + (len(lines) - 5) // 2  # a data line in the middle (echo, status, stamp come first)
            lines[n] = lines[n][:-1] + bytes([0x30 + (lines[n][-1] - 0x30 + 1) % 64])
            frame = b"\n".join(lines)
        elif fault == "truncate":
            frame = frame[: len(frame) // 2]
        self.frames.append(EmulatorFrame(len(self.frames), index, fault, stamp))
        return frame

    # ------------------------------------------------------------------ commands
    def answer(self, line: bytes) -> bytes:
        """The reply to one command line (without its LF/CR); starting a stream makes :meth:`next_frame`
        produce frames."""
        self.commands.append(line)
        if not self.scip2:
            if line == SWITCH_COMMAND:
                self.scip2 = True
                return SWITCH_COMMAND + b"\n0\n\n"
            return line + b"\nE\n\n"  # a SCIP 1.1 firmware's refusal: echo and a one-character status
        if line == SWITCH_COMMAND:
            return encode_reply(line, "0E")
        name, _, tag = line.partition(b";")
        cmd = name[:2].decode("ascii", "replace")
        if cmd in ("MD", "MS", "GD", "GS"):
            return self._answer_scan(line)
        if len(name) != 2:
            return encode_reply(line, "0C")
        if cmd == "BM":
            was, self.laser = self.laser, True
            return encode_reply(line, "02" if was else "00")
        if cmd in ("QT", "RS"):
            self.stream, self.laser = None, False
            if cmd == "RS":
                self.timer_ms = 0.0
            return encode_reply(line, "00")
        if cmd in ("VV", "PP", "II"):
            return encode_info_reply(cmd, self._info(cmd), tag.decode("ascii", "replace"))
        return encode_reply(line, "0D")

    def _answer_scan(self, line: bytes) -> bytes:
        request, status = parse_scan_command(line)
        if request is None:
            return encode_reply(line, status)
        if request.end_step >= self.params.steps_per_turn:
            return encode_reply(line, "04")
        if request.continuous:
            self.stream, self.laser, self._left = request, True, request.scans
            return encode_reply(line, "00")
        if not self.laser:
            return encode_reply(line, "10")
        frame = self._frame(request, remaining=0)
        return frame if frame is not None else encode_reply(line, "50")  # no scans left: "hardware trouble"

    def _info(self, cmd: str) -> list[tuple[str, str]]:
        if cmd == "VV":
            return list(_VERSIONS)
        if cmd == "PP":
            return self.params.fields()
        return [
            ("MODL", self.params.model),
            ("LASR", "ON" if self.laser else "OFF"),
            ("SCSP", f"Initial({self.params.scan_rpm}[rpm])"),
            ("MESM", "Measuring by Normal Mode" if self.stream else "Idle"),
            ("SBPS", "115200[bps]"),
            ("TIME", f"{round(self.timer_ms) % TIMESTAMP_MODULUS:06X}"),
            ("STAT", "Sensor works well."),
        ]
