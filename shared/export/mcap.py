"""The map as an MCAP file for Foxglove (and ``ros2 bag``): ROS 2 messages written with ``rosbags``.

One file, three topics, each with one message stamped at the map's ``stamp_s``, all in the ``map`` frame:

- ``/linemap/map`` (``visualization_msgs/msg/MarkerArray``): the walls as one ``LINE_LIST`` marker
  (namespace ``walls``; two points per segment, z = 0) and the cluster centroids as one ``POINTS`` marker
  (namespace ``centroids``);
- ``/linemap/trajectory`` (``nav_msgs/msg/Path``): one pose per trajectory row, stamped with its ``stamp_s``;
- ``/linemap/pose`` (``geometry_msgs/msg/PoseStamped``): the robot's last pose.

Coordinates are float64 in the messages, so segments, centroids and positions read back exactly; headings
travel as quaternions (back within ~1e-15 rad) and stamps as integer nanoseconds (back within 1 ns).
The file is a rosbag2 MCAP storage file (its rosbag2 metadata inside); it appears whole or not at all.
:func:`read_map_mcap` reads it back. O(segments + centroids + poses) time and memory.
"""

from __future__ import annotations

import functools
import logging
import math
import os
import shutil
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from rosbags.highlevel import AnyReader
from rosbags.interfaces import Nodetype
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from shared.errors import InvalidInputError
from shared.export.errors import ExportIOError, McapMapError
from shared.pipeline.snapshot import MapSnapshot
from shared.types import FloatArray, Pose2D

__all__ = ["MCAP_TOPICS", "McapMap", "read_map_mcap", "write_map_mcap"]

_log = logging.getLogger(__name__)

TOPIC_MAP = "/linemap/map"
TOPIC_TRAJECTORY = "/linemap/trajectory"
TOPIC_POSE = "/linemap/pose"
#: Topic -> message type of what :func:`write_map_mcap` writes.
MCAP_TOPICS = {
    TOPIC_MAP: "visualization_msgs/msg/MarkerArray",
    TOPIC_TRAJECTORY: "nav_msgs/msg/Path",
    TOPIC_POSE: "geometry_msgs/msg/PoseStamped",
}
_NS = 1_000_000_000
_LINE_LIST, _POINTS = 5, 8
_WALL_WIDTH_M = 0.03
_CENTROID_SIZE_M = 0.08
_WALL_RGBA = (0.12, 0.16, 0.22, 1.0)
_CENTROID_RGBA = (0.90, 0.45, 0.10, 1.0)
_PRIMITIVE_DEFAULTS: dict[str, Any] = {"string": "", "bool": False, "float32": 0.0, "float64": 0.0}


def _layer(name: str, value: ArrayLike, cols: int) -> FloatArray:
    """``value`` as a read-only float64 ``(N, cols)`` copy; an empty input gives ``(0, cols)``."""
    arr = np.array(value, dtype=np.float64, copy=True)
    if arr.size == 0:
        arr = np.zeros((0, cols))
    if arr.ndim != 2 or arr.shape[1] != cols:
        raise InvalidInputError(f"McapMap.{name} has shape {arr.shape}: expected (N, {cols})")
    if not np.isfinite(arr).all():
        raise InvalidInputError(f"McapMap.{name} holds non-finite values: expected finite metres / radians")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, slots=True)
class McapMap:
    """What an MCAP map file holds: ``segments`` ``(L, 4)`` ``[x0, y0, x1, y1]`` m, ``centroids`` ``(C, 2)``,
    ``trajectory`` ``(T, 4)`` ``[stamp_s, x_m, y_m, theta_rad]``, the last ``pose`` (or ``None``) and the
    map's ``stamp_s`` (>= 0), in frame ``frame_id``. Arrays are float64 copies, read-only."""

    segments: FloatArray
    centroids: FloatArray
    trajectory: FloatArray
    pose: Pose2D | None = None
    stamp_s: float = 0.0
    frame_id: str = "map"

    def __post_init__(self) -> None:
        for name, cols in (("segments", 4), ("centroids", 2), ("trajectory", 4)):
            object.__setattr__(self, name, _layer(name, getattr(self, name), cols))
        stamps = [float(self.stamp_s), *self.trajectory[:, 0].tolist()]
        if not all(math.isfinite(s) and 0.0 <= s < 2.0**31 for s in stamps):
            raise InvalidInputError(
                f"McapMap stamps {min(stamps)}..{max(stamps)} s: expected 0 <= stamp < 2^31 s (ROS time)"
            )
        object.__setattr__(self, "stamp_s", float(self.stamp_s))
        if not self.frame_id:
            raise InvalidInputError("McapMap.frame_id is empty: expected a tf frame name such as 'map'")

    @classmethod
    def from_snapshot(cls, snapshot: MapSnapshot, frame_id: str = "map") -> McapMap:
        """The layers of a pipeline :class:`MapSnapshot` (its pose is kept only once it has stepped)."""
        pose = snapshot.pose if len(snapshot.trajectory) else None
        return cls(
            snapshot.segments, snapshot.centroids, snapshot.trajectory, pose, snapshot.stamp_s, frame_id
        )


@functools.cache
def _typestore() -> Typestore:
    """The ROS 2 Humble types, loaded once (their serialisers are compiled on first use and kept)."""
    return get_typestore(Stores.ROS2_HUMBLE)


def _to_ns(stamp_s: float) -> int:
    """The nearest integer nanosecond (exact rational arithmetic, no float rounding of ``s * 1e9``)."""
    return round(Fraction(stamp_s) * _NS)


def _default(ts: Typestore, msgtype: str, **given: Any) -> Any:
    """A message of ``msgtype`` with ``given`` fields and every other one at its zero value (so the code
    does not depend on which optional fields a distribution's type carries)."""
    fields: dict[str, Any] = {}
    definitions: list[tuple[str, tuple[Nodetype, Any]]] = list(ts.fielddefs[msgtype][1])
    for name, (kind, detail) in definitions:
        if name in given:
            fields[name] = given[name]
        elif kind == Nodetype.NAME:
            fields[name] = _default(ts, detail)
        elif kind == Nodetype.BASE:
            fields[name] = _PRIMITIVE_DEFAULTS.get(detail[0], 0)
        else:
            (sub_kind, sub), length = detail
            count = length if kind == Nodetype.ARRAY else 0
            if sub_kind == Nodetype.BASE and sub[0] not in ("string", "bool"):
                fields[name] = np.zeros(count, dtype=np.dtype(sub[0]))
            else:
                fields[name] = [_default(ts, sub) if sub_kind == Nodetype.NAME else "" for _ in range(count)]
    return ts.types[msgtype](**fields)


class _Messages:
    """Builds the messages of one map, all stamped ``stamp_ns`` in ``frame_id``, with one typestore."""

    def __init__(self, ts: Typestore, frame_id: str, stamp_ns: int) -> None:
        self.ts = ts
        self.frame_id = frame_id
        self.stamp_ns = stamp_ns

    def make(self, msgtype: str, **given: Any) -> Any:
        return _default(self.ts, msgtype, **given)

    def header(self, stamp_ns: int) -> Any:
        stamp = self.make("builtin_interfaces/msg/Time", sec=stamp_ns // _NS, nanosec=stamp_ns % _NS)
        return self.make("std_msgs/msg/Header", stamp=stamp, frame_id=self.frame_id)

    def point(self, x: float, y: float) -> Any:
        return self.make("geometry_msgs/msg/Point", x=x, y=y, z=0.0)

    def pose(self, pose: Pose2D, stamp_ns: int) -> Any:
        half = 0.5 * pose.theta_rad
        q = self.make("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=math.sin(half), w=math.cos(half))
        body = self.make("geometry_msgs/msg/Pose", position=self.point(pose.x_m, pose.y_m), orientation=q)
        return self.make("geometry_msgs/msg/PoseStamped", header=self.header(stamp_ns), pose=body)

    def marker(self, ns: str, kind: int, points: list[Any], size_m: float, rgba: tuple[float, ...]) -> Any:
        level = self.make("geometry_msgs/msg/Quaternion", w=1.0)
        return self.make(
            "visualization_msgs/msg/Marker",
            header=self.header(self.stamp_ns),
            ns=ns,
            id=0,
            type=kind,
            action=0,
            pose=self.make("geometry_msgs/msg/Pose", orientation=level),
            scale=self.make("geometry_msgs/msg/Vector3", x=size_m, y=size_m, z=size_m),
            color=self.make("std_msgs/msg/ColorRGBA", r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3]),
            points=points,
        )

    def all(self, m: McapMap) -> dict[str, Any]:
        """Topic -> message for the map ``m``."""
        ends = [(x0, y0, x1, y1) for x0, y0, x1, y1 in m.segments.tolist()]
        walls = [self.point(x, y) for x0, y0, x1, y1 in ends for x, y in ((x0, y0), (x1, y1))]
        centroids = [self.point(x, y) for x, y in m.centroids.tolist()]
        markers = [
            self.marker("walls", _LINE_LIST, walls, _WALL_WIDTH_M, _WALL_RGBA),
            self.marker("centroids", _POINTS, centroids, _CENTROID_SIZE_M, _CENTROID_RGBA),
        ]
        poses = [self.pose(Pose2D(x, y, th), _to_ns(t)) for t, x, y, th in m.trajectory.tolist()]
        out = {
            TOPIC_MAP: self.make(MCAP_TOPICS[TOPIC_MAP], markers=markers),
            TOPIC_TRAJECTORY: self.make(
                MCAP_TOPICS[TOPIC_TRAJECTORY], header=self.header(self.stamp_ns), poses=poses
            ),
        }
        if m.pose is not None:
            out[TOPIC_POSE] = self.pose(m.pose, self.stamp_ns)
        return out


def write_map_mcap(
    path: str | os.PathLike[str], source: MapSnapshot | McapMap, *, frame_id: str = "map"
) -> Path:
    """Write a map (a pipeline :class:`MapSnapshot` or a :class:`McapMap`) to the MCAP file ``path``.

    ``path`` must end in ``.mcap`` and its folder must exist; an existing file is replaced atomically.
    Returns the path. Raises :class:`InvalidInputError` for bad arrays, :class:`McapMapError` for a bad
    name, :class:`ExportIOError` when the file cannot be written.
    """
    target = Path(path)
    if target.suffix.lower() != ".mcap":
        raise McapMapError(f"{target}: suffix {target.suffix!r}: expected .mcap")
    layers = source if isinstance(source, McapMap) else McapMap.from_snapshot(source, frame_id)
    ts = _typestore()
    stamp_ns = _to_ns(layers.stamp_s)
    messages = _Messages(ts, layers.frame_id, stamp_ns).all(layers)
    if not target.parent.is_dir():
        raise ExportIOError(f"cannot write {target}: folder {target.parent} does not exist")
    # rosbags writes a folder holding <folder name>.mcap: name the folder so that the file (and the name
    # the file's own rosbag2 metadata records) is the target's name
    scratch = target.parent / f".{target.name}.{os.getpid()}.tmp"
    shutil.rmtree(scratch, ignore_errors=True)
    work = scratch / target.stem
    try:
        with Writer(work, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
            for topic, msg in messages.items():
                msgtype = MCAP_TOPICS[topic]
                conn = writer.add_connection(topic, msgtype, typestore=ts)
                writer.write(conn, stamp_ns, ts.serialize_cdr(msg, msgtype))
        written = work / f"{work.name}.mcap"
        with written.open("rb") as fh:
            os.fsync(fh.fileno())
        os.replace(written, target)
    except Exception as exc:
        raise ExportIOError(f"cannot write {target}: {exc}") from exc
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    _log.debug("wrote %s: %d segments, %d poses", target, len(layers.segments), len(layers.trajectory))
    return target


def _yaw(q: Any) -> float:
    x, y, z, w = float(q.x), float(q.y), float(q.z), float(q.w)
    return math.atan2(2.0 * (w * z + x * y), w * w + x * x - y * y - z * z)


def _xy(points: Any) -> list[tuple[float, float]]:
    return [(float(p.x), float(p.y)) for p in points]


def read_map_mcap(path: str | os.PathLike[str]) -> McapMap:
    """Read back a file written by :func:`write_map_mcap` (the first message of each topic).

    Raises :class:`ExportIOError` if the file is missing, :class:`McapMapError` if it is not an MCAP map.
    """
    source = Path(path)
    if not source.is_file():
        raise ExportIOError(f"cannot read {source}: no such file")
    try:
        with AnyReader([source]) as bag:
            found: dict[str, Any] = {}
            for conn, _, raw in bag.messages([c for c in bag.connections if c.topic in MCAP_TOPICS]):
                if conn.topic not in found:
                    found[conn.topic] = bag.deserialize(raw, conn.msgtype)
    except Exception as exc:
        raise McapMapError(f"{source}: cannot read it as an MCAP map ({exc})") from exc
    if TOPIC_MAP not in found or TOPIC_TRAJECTORY not in found:
        raise McapMapError(
            f"{source}: no {TOPIC_MAP} and {TOPIC_TRAJECTORY} messages: expected a map written by linemap"
        )
    markers = {(m.ns, int(m.type)): m for m in found[TOPIC_MAP].markers}
    walls = markers.get(("walls", _LINE_LIST))
    cents = markers.get(("centroids", _POINTS))
    if walls is None or cents is None or len(walls.points) % 2:
        raise McapMapError(f"{source}: {TOPIC_MAP} lacks the walls LINE_LIST or the centroids POINTS marker")
    wall_xy = np.array(_xy(walls.points), dtype=np.float64).reshape(-1, 4)
    head = walls.header
    traj = [
        (int(p.header.stamp.sec) * _NS + int(p.header.stamp.nanosec), float(p.pose.position.x),
         float(p.pose.position.y), _yaw(p.pose.orientation))
        for p in found[TOPIC_TRAJECTORY].poses
    ]  # fmt: skip
    pose_msg = found.get(TOPIC_POSE)
    pose = None
    if pose_msg is not None:
        pp = pose_msg.pose
        pose = Pose2D(float(pp.position.x), float(pp.position.y), _yaw(pp.orientation))
    return McapMap(
        wall_xy,
        np.array(_xy(cents.points), dtype=np.float64).reshape(-1, 2),
        np.array([(t / _NS, x, y, th) for t, x, y, th in traj], dtype=np.float64).reshape(-1, 4),
        pose,
        (int(head.stamp.sec) * _NS + int(head.stamp.nanosec)) / _NS,
        str(head.frame_id) or "map",
    )
