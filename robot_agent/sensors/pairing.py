"""Pairing each laser scan with the wheel-odometry pose at the scan's time stamp (docs/design.md §2, §3).

The laser (10 Hz) and the encoder bridge (20-100 Hz) run on their own clocks; both sources stamp on the
host's clock (the serial drivers' ``clock``, :func:`time.time` by default; the simulator's for ``sim``).
A scan at ``t`` gets the pose interpolated between the two odometry readings that bracket ``t``: position
linearly, heading along the shorter arc of the circle. A scan newer than the newest reading waits until a
newer reading arrives. The gap of a scan is its distance in time to the nearest reading; a scan whose gap
exceeds ``max_gap_s`` (the odometry stalled or had not started) gets no pose: it is dropped or flagged
(yielded with ``odometry=None``). Before the first reading, or after the last one once the odometry has
ended, the nearest reading's pose is held if it is within ``max_gap_s``.

:class:`ScanPairer` is the push-style core (pure, no I/O, no threads): O(log n) per scan in the readings
kept, which are pruned as scans pass (amortised O(1) each). :func:`paired_scans` is the pull-style
generator for the agent's scan source: it reads odometry only as far as the current scan needs.
"""

from __future__ import annotations

import bisect
import logging
import math
from collections import deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, replace
from typing import Literal, Protocol

from shared.errors import InvalidInputError
from shared.types import Pose2D, Scan, wrap_angle

__all__ = [
    "Paired",
    "PairingStats",
    "PoseTrack",
    "ScanPairer",
    "StampedPose",
    "interpolate_pose",
    "paired_scans",
]

_log = logging.getLogger(__name__)


class StampedPose(Protocol):
    """Anything with a host time stamp (s) and a robot pose, e.g. an odometry reading."""

    @property
    def stamp_s(self) -> float: ...

    @property
    def pose(self) -> Pose2D: ...


def _lerp(a: float, b: float, f: float) -> float:
    value = (1.0 - f) * a + f * b
    return min(max(value, min(a, b)), max(a, b))


def interpolate_pose(t0_s: float, pose0: Pose2D, t1_s: float, pose1: Pose2D, t_s: float) -> Pose2D:
    """The pose at ``t_s`` between ``pose0`` at ``t0_s`` and ``pose1`` at ``t1_s`` (``t0_s <= t_s <= t1_s``).

    Position is linear in time; the heading turns along the shorter arc from ``pose0`` to ``pose1`` (for
    exactly opposite headings, counter-clockwise). At ``t0_s`` and ``t1_s`` the poses come back exactly.
    O(1).
    """
    if not t0_s <= t_s <= t1_s:
        raise InvalidInputError(
            f"interpolate_pose at t = {t_s!r} s: expected a time between {t0_s!r} s and {t1_s!r} s"
        )
    if t_s == t1_s:
        return pose1
    if t_s == t0_s:
        return pose0
    f = (t_s - t0_s) / (t1_s - t0_s)
    turn = wrap_angle(pose1.theta_rad - pose0.theta_rad)
    return Pose2D(_lerp(pose0.x_m, pose1.x_m, f), _lerp(pose0.y_m, pose1.y_m, f), pose0.theta_rad + f * turn)


class PoseTrack:
    """Odometry poses in strictly increasing time. Appending and pruning are amortised O(1); the pose at a
    time is found by bisection, O(log n) in the poses kept."""

    def __init__(self) -> None:
        self._stamps: list[float] = []
        self._poses: list[Pose2D] = []
        self._head = 0

    def __len__(self) -> int:
        return len(self._stamps) - self._head

    @property
    def first_stamp_s(self) -> float | None:
        """Time of the oldest pose kept (None if empty)."""
        return self._stamps[self._head] if len(self) else None

    @property
    def last_stamp_s(self) -> float | None:
        """Time of the newest pose (None if empty)."""
        return self._stamps[-1] if len(self) else None

    def append(self, stamp_s: float, pose: Pose2D) -> bool:
        """Add a pose; one not strictly newer than the last (or not finite) is ignored: returns False."""
        if not math.isfinite(stamp_s) or (len(self) and stamp_s <= self._stamps[-1]):
            return False
        self._stamps.append(stamp_s)
        self._poses.append(pose)
        return True

    def pose_at(self, t_s: float) -> tuple[Pose2D, float] | None:
        """The pose at ``t_s`` and the gap (s) to the nearest pose kept; None if empty or ``t_s`` is after
        the newest pose. Before the oldest pose, that pose is returned (with its gap)."""
        if not len(self) or t_s > self._stamps[-1]:
            return None
        i = bisect.bisect_left(self._stamps, t_s, self._head)
        t1, p1 = self._stamps[i], self._poses[i]
        if t1 == t_s or i == self._head:
            return p1, t1 - t_s
        t0, p0 = self._stamps[i - 1], self._poses[i - 1]
        return interpolate_pose(t0, p0, t1, p1, t_s), min(t_s - t0, t1 - t_s)

    def last(self) -> tuple[float, Pose2D] | None:
        """The newest ``(stamp_s, pose)``, None if empty."""
        return (self._stamps[-1], self._poses[-1]) if len(self) else None

    def prune_before(self, t_s: float) -> None:
        """Forget the poses older than the newest one at or before ``t_s`` (later times still bracket)."""
        keep = bisect.bisect_right(self._stamps, t_s, self._head) - 1
        if keep > self._head:
            self._head = keep
        if self._head > 64 and self._head * 2 > len(self._stamps):
            del self._stamps[: self._head]
            del self._poses[: self._head]
            self._head = 0


@dataclass(frozen=True, slots=True)
class Paired:
    """A scan and its odometry pose (None: no reading within the maximum gap); ``gap_s`` is the time to the
    nearest reading (inf if there was none)."""

    scan: Scan
    pose: Pose2D | None
    gap_s: float


@dataclass(slots=True)
class PairingStats:
    """Scans paired by interpolation or at a reading, held at the first or last reading, left without a
    pose (gap too large), and odometry readings used or ignored (not newer than the last)."""

    paired: int = 0
    held: int = 0
    unpaired: int = 0
    readings: int = 0
    ignored_readings: int = 0


class ScanPairer:
    """Push-style pairing of scans with odometry readings (see the module docstring).

    :meth:`add_reading` and :meth:`add_scan` return the scans they settle, in scan order, as
    :class:`Paired`; a scan newer than the newest reading is kept until a reading reaches its time, or
    :meth:`finish` says no more will come. At most ``max_pending`` scans wait: beyond that the oldest is
    settled with what is known. O(log n) per scan, amortised O(1) per reading.
    """

    def __init__(self, max_gap_s: float = 0.1, *, max_pending: int = 100, stats: PairingStats | None = None):
        if not (math.isfinite(max_gap_s) and max_gap_s >= 0.0):
            raise InvalidInputError(f"max_gap_s = {max_gap_s!r}: expected a finite time >= 0 s")
        if max_pending < 1:
            raise InvalidInputError(f"max_pending = {max_pending!r}: expected at least 1 scan")
        self.max_gap_s = max_gap_s
        self.max_pending = max_pending
        self.stats = stats if stats is not None else PairingStats()
        self.track = PoseTrack()
        self.finished = False
        self._pending: deque[Scan] = deque()

    @property
    def pending(self) -> int:
        """Scans waiting for a newer reading."""
        return len(self._pending)

    def add_reading(self, stamp_s: float, pose: Pose2D) -> list[Paired]:
        """Add an odometry reading (host time s, robot pose); returns the scans it settles."""
        if self.track.append(stamp_s, pose):
            self.stats.readings += 1
        else:
            self.stats.ignored_readings += 1
            _log.debug(
                "odometry reading at %r s ignored: not newer than %r s", stamp_s, self.track.last_stamp_s
            )
        return self._release()

    def add_scan(self, scan: Scan) -> list[Paired]:
        """Queue a scan; returns the scans settled now (this one too, if a reading reached its time)."""
        self._pending.append(scan)
        out = self._release()
        while len(self._pending) > self.max_pending:
            out.append(self._settle(self._pending.popleft()))
        return out

    def finish(self) -> list[Paired]:
        """No more readings will come: settle the waiting scans (and any later ones at once)."""
        self.finished = True
        return self._release()

    def _release(self) -> list[Paired]:
        out: list[Paired] = []
        last = self.track.last_stamp_s
        while self._pending and (self.finished or (last is not None and last >= self._pending[0].stamp_s)):
            out.append(self._settle(self._pending.popleft()))
        return out

    def _settle(self, scan: Scan) -> Paired:
        t = scan.stamp_s
        found = self.track.pose_at(t)
        held = False
        if found is None:
            newest = self.track.last()
            found = (newest[1], t - newest[0]) if newest is not None else None
            held = True
        elif self.track.first_stamp_s is not None and t < self.track.first_stamp_s:
            held = True
        pose, gap = found if found is not None else (None, math.inf)
        if pose is not None and gap <= self.max_gap_s:
            if held:
                self.stats.held += 1
            else:
                self.stats.paired += 1
            self.track.prune_before(t)
            return Paired(scan, pose, gap)
        self.stats.unpaired += 1
        return Paired(scan, None, gap)


def paired_scans(
    scans: Iterable[Scan],
    odometry: Iterable[StampedPose],
    *,
    max_gap_s: float = 0.1,
    on_gap: Literal["drop", "flag"] = "drop",
    stats: PairingStats | None = None,
) -> Iterator[Scan]:
    """``scans`` with ``odometry`` set to the wheel-odometry pose at each scan's time (see the module
    docstring); both streams in increasing time on the same clock.

    Reads ``odometry`` (e.g. an :class:`~robot_agent.sensors.encoders.OdometrySource`) only as far as the
    current scan needs, blocking on it while a scan is newer than the newest reading. A scan with no reading
    within ``max_gap_s`` is dropped (logged) or, with ``on_gap="flag"``, yielded with ``odometry=None``.
    ``stats`` (optional) is filled in as it goes. O(log n) per scan.
    """
    if on_gap not in ("drop", "flag"):
        raise InvalidInputError(f"on_gap = {on_gap!r}: expected 'drop' or 'flag'")
    pairer = ScanPairer(max_gap_s, stats=stats)
    readings = iter(odometry)
    exhausted = False
    for scan in scans:
        settled = pairer.add_scan(scan)
        while pairer.pending and not exhausted:
            try:
                reading = next(readings)
            except StopIteration:
                exhausted = True
                settled += pairer.finish()
                break
            settled += pairer.add_reading(reading.stamp_s, reading.pose)
        yield from _emit(settled, on_gap, pairer)
    yield from _emit(pairer.finish(), on_gap, pairer)


def _emit(settled: list[Paired], on_gap: str, pairer: ScanPairer) -> Iterator[Scan]:
    unpaired = pairer.stats.unpaired
    for item in settled:
        if item.pose is not None:
            yield replace(item.scan, odometry=item.pose)
            continue
        level = logging.WARNING if unpaired <= 10 or unpaired % 100 == 0 else logging.DEBUG
        _log.log(
            level,
            "scan at %.3f s: no odometry reading within %.3f s (nearest %.3f s away); %s",
            item.scan.stamp_s,
            pairer.max_gap_s,
            item.gap_s,
            "dropped" if on_gap == "drop" else "flagged (odometry=None)",
        )
        if on_gap == "flag":
            yield replace(item.scan, odometry=None)
