"""Laser log input and output: streaming readers of CARMEN and BreezySLAM logs and of ROS bags (ROS 1
``.bag``, rosbag2 SQLite3 / MCAP), and a CARMEN writer.

``open_log(path)`` detects the format and returns a :class:`LogReader` (a context manager and iterator of
:class:`shared.types.Scan`, each with the robot's odometry pose); ``write_carmen(path, scans)`` writes scans
back as a CARMEN log. Errors derive from :class:`LogError` (itself a :class:`shared.errors.LinemapError`).
"""

from __future__ import annotations

from shared.io.breezyslam import BreezySlamReader
from shared.io.carmen import CarmenReader, write_carmen
from shared.io.errors import (
    LogError,
    LogFormatError,
    LogNotFoundError,
    RosbagError,
    RosbagMessageError,
    RosbagTopicError,
    UnknownLogFormatError,
)
from shared.io.logs import FORMATS, detect_format, open_log
from shared.io.reader import LogInfo, LogReader
from shared.io.rosbag import RosbagReader

__all__ = [
    "FORMATS",
    "BreezySlamReader",
    "CarmenReader",
    "LogError",
    "LogFormatError",
    "LogInfo",
    "LogNotFoundError",
    "LogReader",
    "RosbagError",
    "RosbagMessageError",
    "RosbagReader",
    "RosbagTopicError",
    "UnknownLogFormatError",
    "detect_format",
    "open_log",
    "write_carmen",
]
