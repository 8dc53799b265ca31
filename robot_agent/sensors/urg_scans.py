"""From the URG-04LX's SCIP 2.0 scan frames to :class:`shared.types.Scan`: the sensor's 24-bit millisecond
time stamps mapped to host seconds (:class:`ClockMapper`) and a frame's ranges and angles
(:func:`scan_from_frame`: metres, NaN for error codes, angles from PP's AFRT and ARES, a cluster of steps
at its middle step). Pure, no I/O; O(1) per stamp, O(beams) per scan.
"""

from __future__ import annotations

from robot_agent.sensors.scip import TIMESTAMP_MODULUS, unwrap_timestamp
from robot_agent.sensors.scip_info import SensorParams
from robot_agent.sensors.scip_scan import ScanFrame, angle_of_value
from shared.types import Scan

__all__ = ["ClockMapper", "scan_from_frame"]


class ClockMapper:
    """Maps the sensor's 24-bit millisecond time stamps to host seconds, strictly increasing.

    The offset host - sensor is the smallest seen so far (the frame that came with the least delay),
    allowed to grow by at most ``drift_ratio`` of the host time elapsed (clock drift); the sensor time is
    unwrapped against the previous stamp plus the host time elapsed, so a 24-bit wrap is seamless.
    :meth:`restart` forgets the sensor's timeline (its timer restarts with a power cycle) but keeps the
    stamps increasing. O(1) per stamp.
    """

    def __init__(self, drift_ratio: float = 1e-3) -> None:
        self.drift_ratio = drift_ratio
        self._sensor_ms: int | None = None
        self._host_s = 0.0
        self._offset_s = 0.0
        self._last_s: float | None = None

    def restart(self) -> None:
        """Forget the sensor timeline (after a reconnect)."""
        self._sensor_ms = None

    def stamp(self, raw_ms: int, host_s: float) -> float:
        """Host time (s) of the scan stamped ``raw_ms`` by the sensor, received at ``host_s``."""
        if self._sensor_ms is None:
            sensor_ms = raw_ms % TIMESTAMP_MODULUS
            self._offset_s = host_s - sensor_ms / 1000.0
        else:
            expected = self._sensor_ms + (host_s - self._host_s) * 1000.0
            sensor_ms = unwrap_timestamp(raw_ms % TIMESTAMP_MODULUS, expected)
            candidate = host_s - sensor_ms / 1000.0
            if candidate < self._offset_s:
                self._offset_s = candidate
            else:
                grow = self.drift_ratio * max(host_s - self._host_s, 0.0)
                self._offset_s += min(candidate - self._offset_s, grow)
        self._sensor_ms, self._host_s = sensor_ms, host_s
        stamp = sensor_ms / 1000.0 + self._offset_s
        if self._last_s is not None and stamp <= self._last_s:
            stamp = self._last_s + 1e-6
        self._last_s = stamp
        return stamp


def scan_from_frame(frame: ScanFrame, params: SensorParams, stamp_s: float) -> Scan:
    """A :class:`Scan` of ``frame``: metres, NaN for error codes, angles from PP (AFRT, ARES)."""
    angle_min, increment = angle_of_value(frame.request, params.front_step, params.steps_per_turn)
    return Scan(stamp_s, angle_min, increment, params.range_min_m, params.range_max_m, frame.ranges_m())
