"""The server's recent map versions (server.recentmaps): kept per robot up to a bound, the least recently
used robot going first, and never more rows than the budget."""

from __future__ import annotations

from server.recentmaps import RecentMaps
from server.schemas import MapOut


def _map(robot: int, version: int, poses: int = 1) -> MapOut:
    return MapOut(
        robot_id=robot,
        version=version,
        stamp_s=float(version),
        segments=[[1.0, 0.0, 0.0, 1.0, 0.0]],
        centroids=[],
        pose=[0.0, 0.0, 0.0],
        trajectory=[[float(i), 0.0, 0.0, 0.0] for i in range(poses)],
    )


def test_the_last_versions_of_each_robot_are_kept() -> None:
    recent = RecentMaps(per_robot=3, robots=2)
    for v in range(1, 6):
        recent.put(_map(1, v))
    assert recent.held(1) == [3, 4, 5]
    assert recent.get(1, 2) is None and recent.get(1, 5) is not None
    recent.put(_map(2, 1))
    recent.put(_map(1, 6))  # robot 1 used last: robot 2 is the least recently used
    recent.put(_map(3, 1))
    assert recent.held(2) == [] and recent.held(1) == [4, 5, 6] and recent.held(3) == [1]
    recent.forget(1)
    assert recent.held(1) == [] and recent.get(1, 6) is None


def test_the_row_budget_holds() -> None:
    recent = RecentMaps(per_robot=4, robots=8, max_rows=100)
    recent.put(_map(1, 1, poses=40))  # 41 rows
    recent.put(_map(2, 1, poses=40))  # 82
    recent.put(_map(2, 2, poses=40))  # 123 > 100: robot 1's version goes
    assert recent.held(1) == [] and recent.held(2) == [1, 2]
    recent.put(_map(3, 1, poses=200))  # larger than the whole budget: not kept, nothing evicted
    assert recent.held(3) == [] and recent.held(2) == [1, 2]
