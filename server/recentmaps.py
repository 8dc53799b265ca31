"""The last few versions of each robot's map that this server process has read, so that files asked for
one after the other can be of one version (``?version=N`` on ``/maps/latest`` and the exports: a PGM and
the YAML that names it).

The database holds only each robot's current map (a delta replaces walls in place), so an older version
can be served only from here: a version this process read whole within the last :data:`PER_ROBOT` such
reads of that robot's map. Bounded: at most :data:`PER_ROBOT` versions of at most :data:`ROBOTS` robots
and :data:`MAX_ROWS` rows (walls, centroids and trajectory poses) in all, the least recently used robot's
oldest versions going first; a map larger than that is not kept. Thread-safe; O(1) per call but
evictions.
"""

from __future__ import annotations

import threading
from collections import OrderedDict

from server.schemas import MapOut

__all__ = ["MAX_ROWS", "PER_ROBOT", "ROBOTS", "RecentMaps"]

#: versions kept per robot
PER_ROBOT = 4
#: robots kept
ROBOTS = 64
#: rows kept in all (about 100 bytes each as Python lists)
MAX_ROWS = 2_000_000


def _rows(m: MapOut) -> int:
    return len(m.segments) + len(m.centroids) + len(m.trajectory)


class RecentMaps:
    """Map versions by robot, most recent last (module docstring)."""

    def __init__(self, per_robot: int = PER_ROBOT, robots: int = ROBOTS, max_rows: int = MAX_ROWS) -> None:
        self._per_robot = per_robot
        self._robots = robots
        self._max_rows = max_rows
        self._total = 0
        self._maps: OrderedDict[int, OrderedDict[int, MapOut]] = OrderedDict()
        self._lock = threading.Lock()

    def put(self, m: MapOut) -> None:
        """Keep ``m`` (a whole map, trajectory included) under its robot and version."""
        if _rows(m) > self._max_rows:
            return
        with self._lock:
            versions = self._maps.setdefault(m.robot_id, OrderedDict())
            self._maps.move_to_end(m.robot_id)
            old = versions.pop(m.version, None)
            self._total += _rows(m) - (_rows(old) if old is not None else 0)
            versions[m.version] = m
            while len(versions) > self._per_robot:
                self._total -= _rows(versions.popitem(last=False)[1])
            while len(self._maps) > self._robots or self._total > self._max_rows:
                robot, oldest = next(iter(self._maps.items()))
                if oldest:
                    self._total -= _rows(oldest.popitem(last=False)[1])
                if not oldest:
                    self._maps.pop(robot)

    def get(self, robot_id: int, version: int) -> MapOut | None:
        """Version ``version`` of the robot's map if it is kept here."""
        with self._lock:
            versions = self._maps.get(robot_id)
            return None if versions is None else versions.get(version)

    def held(self, robot_id: int) -> list[int]:
        """The versions of the robot's map kept here, ascending."""
        with self._lock:
            return sorted(self._maps.get(robot_id) or ())

    def forget(self, robot_id: int) -> None:
        """Drop every version of the robot's map (the robot was deleted)."""
        with self._lock:
            versions = self._maps.pop(robot_id, None)
            for m in (versions or {}).values():
                self._total -= _rows(m)
