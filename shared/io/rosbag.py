"""Streaming reader of ROS bags without ROS (via ``rosbags``): ROS 1 ``.bag``, rosbag2 folders (SQLite3 or
MCAP storage) and bare ``.db3`` / ``.mcap`` files.

Topics (docs/design.md §3's scan model is ROS's ``sensor_msgs/LaserScan``):

- scans: the bag's only ``sensor_msgs/LaserScan`` topic, or the one named by ``scan_topic``;
- odometry: the ``nav_msgs/Odometry`` topic (``odom_topic``; among several, ``/odom``), else the
  ``odom_frame -> base_frame`` transforms on ``/tf`` (``tf2_msgs/TFMessage`` or ROS 1 ``tf/tfMessage``),
  else none (scans then carry no odometry);
- laser offset (:attr:`LogInfo.laser_offset`): the chain of transforms on ``/tf_static`` (else among the
  first messages of ``/tf``) from the odometry's child frame (``base_frame`` by default) to the scan's
  ``header.frame_id``, reduced to 2D; identity if there is none.

Each scan gets ``stamp_s`` = its header stamp (``sec + nanosec``), ranges widened exactly from float32 (NaN
and inf kept: no return), and ``odometry`` = the odometry pose interpolated at that stamp between the
bracketing odometry messages (:class:`~shared.io.rosbag_pose.OdometryTrack`); scans outside the odometry's
time span get the nearest pose (counted in :attr:`RosbagReader.clamped_scans`). Messages stream in bag
order: memory is O(beams) per scan plus a few pending scans and a short odometry buffer. Opening the bag
and reading its messages: :class:`~shared.io.rosbag_bag.BagFile`.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Iterator, Sequence
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np
from rosbags.interfaces import Connection

from shared.errors import InvalidInputError
from shared.io.errors import LogNotFoundError, RosbagMessageError
from shared.io.reader import LogInfo, LogReader
from shared.io.rosbag_bag import BagFile
from shared.io.rosbag_pose import OdometryTrack, Transform3D, chain_transform, yaw_from_quaternion
from shared.io.rosbag_topics import LASER_SCAN_TYPE, ODOMETRY_TYPE, TF_TYPES, choose_topic
from shared.types import BeamGeometry, Pose2D, Scan

__all__ = ["LASER_SCAN_TYPE", "ODOMETRY_TYPE", "TF_TYPES", "RosbagReader"]

logger = logging.getLogger(__name__)

#: How many ``/tf`` messages are searched for the laser's mounting transform when ``/tf_static`` lacks it.
_TF_PEEK_MESSAGES = 2000
_MAX_STATIC_MESSAGES = 10000
#: Scans waiting for a later odometry message; beyond this the oldest gets the latest pose.
_MAX_PENDING_SCANS = 256
_MAX_ODOMETRY_POSES = 4096
_NS = 1_000_000_000
_TILT_WARN_RAD = 0.05


def _frame(name: str) -> str:
    """A tf frame name without the leading ``/`` ROS 1 allowed."""
    return name.lstrip("/")


def _stamp_ns(header: Any) -> int:
    return int(header.stamp.sec) * _NS + int(header.stamp.nanosec)


def _transform(msg: Any) -> Transform3D:
    t, r = msg.translation, msg.rotation
    return Transform3D((float(t.x), float(t.y), float(t.z)), (float(r.x), float(r.y), float(r.z), float(r.w)))


class RosbagReader(LogReader):
    """Stream the scans of a ROS bag (path: a ``.bag`` file, a rosbag2 folder, a ``.db3`` or ``.mcap``).

    ``scan_topic`` / ``odom_topic`` choose topics (the leading ``/`` may be left out); ``odom_frame`` and
    ``base_frame`` name the tf frames used when the odometry comes from ``/tf``. Opening reads the topic
    list, the static transforms and the first scan, so :attr:`info` is complete at once. Raises
    :class:`LogNotFoundError`, :class:`RosbagError` (unreadable bag), :class:`RosbagTopicError` (missing,
    ambiguous or mistyped topic) and, while iterating, :class:`RosbagMessageError`.
    """

    format_name = "rosbag"

    def __init__(
        self,
        path: Path | str,
        *,
        scan_topic: str | None = None,
        odom_topic: str | None = None,
        odom_frame: str = "odom",
        base_frame: str = "base_link",
    ) -> None:
        self.path = Path(path)
        self._pending: list[Scan] = []
        self.scans_read = 0
        self.lines_read = 0
        self.clamped_scans = 0
        if not self.path.exists():
            raise LogNotFoundError(f"log file not found: {self.path}")
        self._ros1 = self.path.suffix == ".bag" and self.path.is_file()
        self._bag = BagFile(self.path, ros1=self._ros1)
        try:
            self._setup(scan_topic, odom_topic, _frame(odom_frame), _frame(base_frame))
        except BaseException:
            self.close()
            raise

    def progress(self) -> float | None:
        """The share of the bag's scan messages read so far (from the bag's message counts); ``None``
        when the bag does not count them. O(connections)."""
        total = sum(int(getattr(c, "msgcount", 0) or 0) for c in self._scan_conns)
        return min(1.0, self.scans_read / total) if total > 0 else None

    def _setup(
        self, scan_topic: str | None, odom_topic: str | None, odom_frame: str, base_frame: str
    ) -> None:
        topics = self._bag.topics
        self.topics: dict[str, str] = topics
        name = self.path.name
        scan = choose_topic(
            name, topics, scan_topic, (LASER_SCAN_TYPE,), "--topic (scan_topic)", required=True
        )
        assert scan is not None
        self.scan_topic: str = scan
        self._scan_conns = self._bag.connections(scan)
        self.odom_topic = choose_topic(
            name, topics, odom_topic, (ODOMETRY_TYPE,), "--odom-topic (odom_topic)", required=False
        )
        self._odom_frame, self._base_frame = odom_frame, base_frame
        tf_topics = sorted(t for t, ty in topics.items() if ty in TF_TYPES and not t.endswith("tf_static"))
        static_topics = sorted(t for t, ty in topics.items() if ty in TF_TYPES and t.endswith("tf_static"))
        self._odom_conns: list[Connection] = []
        if self.odom_topic is not None:
            self._odom_conns = self._bag.connections(self.odom_topic)
            first = self._bag.first(self._odom_conns)
            if first is not None and _frame(first.child_frame_id):
                base_frame = _frame(first.child_frame_id)
            self.odometry_source = f"{self.odom_topic} ({ODOMETRY_TYPE})"
        elif tf_topics and self._tf_has_odometry(tf_topics):
            self._odom_conns = [c for t in tf_topics for c in self._bag.connections(t)]
            self.odometry_source = f"tf {odom_frame} -> {base_frame}"
        else:
            self.odometry_source = "none"
            logger.warning(
                "%s: no %s topic and no %s -> %s transforms on /tf: scans carry no odometry",
                self.path.name, ODOMETRY_TYPE, odom_frame, base_frame,
            )  # fmt: skip
        first_scan = self._bag.first(self._scan_conns)
        self.laser_frame = _frame(first_scan.header.frame_id) if first_scan is not None else ""
        offset = self._laser_offset(static_topics, tf_topics, base_frame)
        self._scans: Iterator[Scan] = self._read_scans()
        self._prime()
        self._info = LogInfo(
            self.format_name,
            self.path,
            self._geometry(first_scan),
            offset,
            None,
            self._bag.is_compressed(),
            MappingProxyType(
                {
                    "ros_version": "1" if self._ros1 else "2",
                    "storage": self._bag.storage(),
                    "scan_topic": self.scan_topic,
                    "odometry": self.odometry_source,
                    "laser_frame": self.laser_frame,
                    "base_frame": base_frame,
                }
            ),
        )

    def _tf_has_odometry(self, tf_topics: Sequence[str]) -> bool:
        conns = [c for t in tf_topics for c in self._bag.connections(t)]
        gen = self._bag.messages(conns)
        try:
            for count, (_, _, msg) in enumerate(gen):
                if any(self._is_odometry_tf(tr) for tr in msg.transforms):
                    return True
                if count >= _TF_PEEK_MESSAGES:
                    break
        finally:
            gen.close()
        return False

    def _is_odometry_tf(self, tr: Any) -> bool:
        parent, child = _frame(tr.header.frame_id), _frame(tr.child_frame_id)
        return parent == self._odom_frame and child == self._base_frame

    def _laser_offset(self, static_topics: Sequence[str], tf_topics: Sequence[str], base: str) -> Pose2D:
        """The scanner's pose in the ``base`` frame from the tf tree; identity if it is not there."""
        leaf = self.laser_frame
        if not leaf or leaf == base:
            return Pose2D()
        for topics, limit in ((static_topics, _MAX_STATIC_MESSAGES), (tf_topics, _TF_PEEK_MESSAGES)):
            if not topics:
                continue
            parents: dict[str, tuple[str, Transform3D]] = {}
            gen = self._bag.messages([c for t in topics for c in self._bag.connections(t)])
            try:
                for count, (conn, n, msg) in enumerate(gen):
                    for tr in msg.transforms:
                        if self._is_odometry_tf(tr):
                            continue
                        try:
                            transform = _transform(tr.transform)
                        except InvalidInputError as exc:
                            raise RosbagMessageError(
                                f"{self.path.name}: {conn.topic} message {n}: {exc}"
                            ) from exc
                        parents[_frame(tr.child_frame_id)] = (_frame(tr.header.frame_id), transform)
                    chain = chain_transform(parents, base, leaf)
                    if chain is not None:
                        if chain.tilt_rad() > _TILT_WARN_RAD:
                            logger.warning(
                                "%s: laser frame %s is tilted %.3f rad from %s: scans are used as if level",
                                self.path.name, leaf, chain.tilt_rad(), base,
                            )  # fmt: skip
                        return chain.to_pose2d()
                    if count >= limit:
                        break
            finally:
                gen.close()
        logger.info("%s: no transform %s -> %s in the bag: laser offset 0", self.path.name, base, leaf)
        return Pose2D()

    def _geometry(self, msg: Any) -> BeamGeometry | None:
        if msg is None:
            return None
        rate_hz = 10.0
        if float(msg.scan_time) > 0.0:
            rate_hz = round(1.0 / float(msg.scan_time), 6)  # scan_time is float32: 0.1 s -> 10.0 Hz
        else:
            count = sum(c.msgcount for c in self._scan_conns)
            duration_s = self._bag.duration_ns / _NS
            if count > 1 and duration_s > 0.0:
                rate_hz = (count - 1) / duration_s
        scan = self._pending[0] if self._pending else None
        if scan is None:
            return None
        return BeamGeometry(
            scan.angle_min_rad,
            scan.angle_increment_rad,
            scan.beam_count,
            scan.range_min_m,
            scan.range_max_m,
            rate_hz,
        )

    # -- streaming -------------------------------------------------------------------------------------

    def _scan(self, conn: Connection, n: int, msg: Any) -> tuple[int, Scan]:
        stamp_ns = _stamp_ns(msg.header)
        ranges = np.asarray(msg.ranges, dtype=np.float64)
        intensities = np.asarray(msg.intensities, dtype=np.float64)
        try:
            scan = Scan(
                stamp_ns / _NS,
                float(msg.angle_min),
                float(msg.angle_increment),
                float(msg.range_min),
                float(msg.range_max),
                ranges,
                intensities if intensities.size == ranges.size and ranges.size else None,
            )
        except InvalidInputError as exc:
            raise RosbagMessageError(f"{self.path.name}: {conn.topic} message {n}: {exc}") from exc
        return stamp_ns, scan

    def _odometry(self, conn: Connection, n: int, msg: Any) -> Iterator[tuple[int, Pose2D]]:
        """The odometry poses a message carries (one for Odometry, the matching transforms for tf)."""
        try:
            if conn.msgtype == ODOMETRY_TYPE:
                p, q = msg.pose.pose.position, msg.pose.pose.orientation
                yaw = yaw_from_quaternion(float(q.x), float(q.y), float(q.z), float(q.w))
                yield _stamp_ns(msg.header), Pose2D(float(p.x), float(p.y), yaw)
                return
            for tr in msg.transforms:
                if self._is_odometry_tf(tr):
                    yield _stamp_ns(tr.header), _transform(tr.transform).to_pose2d()
        except InvalidInputError as exc:
            raise RosbagMessageError(f"{self.path.name}: {conn.topic} message {n}: {exc}") from exc

    def _with_odometry(self, track: OdometryTrack, stamp_ns: int, scan: Scan) -> Scan:
        try:
            found = track.pose_at(stamp_ns)
        except InvalidInputError as exc:  # finite poses whose interpolation overflows (|x| near 1e308)
            raise RosbagMessageError(
                f"{self.path.name}: scan at {scan.stamp_s:.9f} s: the odometry interpolated at its stamp is "
                f"not finite ({exc})"
            ) from exc
        if found is None:
            return scan
        pose, inside = found
        if not inside:
            self.clamped_scans += 1
            if self.clamped_scans == 1:
                logger.warning(
                    "%s: scan at %.9f s lies outside the odometry's time span: it gets the nearest pose",
                    self.path.name, scan.stamp_s,
                )  # fmt: skip
        return Scan(
            scan.stamp_s, scan.angle_min_rad, scan.angle_increment_rad, scan.range_min_m, scan.range_max_m,
            scan.ranges_m, scan.intensities, odometry=pose,
        )  # fmt: skip

    def _read_scans(self) -> Iterator[Scan]:
        track = OdometryTrack()
        pending: deque[tuple[int, Scan]] = deque()
        scan_topic = self.scan_topic
        with_odometry = bool(self._odom_conns)
        last_ns: int | None = None
        for conn, n, msg in self._bag.messages([*self._scan_conns, *self._odom_conns]):
            if conn.topic == scan_topic:
                pending.append(self._scan(conn, n, msg))
            else:
                for stamp_ns, pose in self._odometry(conn, n, msg):
                    track.add(stamp_ns, pose)
            latest = track.latest_ns
            while pending and (
                not with_odometry
                or (latest is not None and latest >= pending[0][0])
                or len(pending) > _MAX_PENDING_SCANS
            ):
                stamp_ns, scan = pending.popleft()
                last_ns = stamp_ns
                yield self._with_odometry(track, stamp_ns, scan)
            if last_ns is not None:
                oldest = min([last_ns, *(s for s, _ in pending)])
                track.prune(oldest, _MAX_ODOMETRY_POSES)
        while pending:
            stamp_ns, scan = pending.popleft()
            yield self._with_odometry(track, stamp_ns, scan)
        if self.clamped_scans:
            logger.warning(
                "%s: %d scans lay outside the odometry's time span and got the nearest pose",
                self.path.name, self.clamped_scans,
            )  # fmt: skip

    def close(self) -> None:
        """Close the bag; iteration then stops. Idempotent."""
        self._pending.clear()
        scans = getattr(self, "_scans", None)
        if scans is not None:
            close = getattr(scans, "close", None)
            if close is not None:
                close()
        bag = getattr(self, "_bag", None)
        if bag is not None:
            bag.close()
