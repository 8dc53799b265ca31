"""How long a kept trajectory may grow: the rule the robot (its Robot DB and its snapshots) and the server
(its stored map) both apply, so that neither the uploads nor the stored map grow with the run's length.

A trajectory of more than :data:`MAX_TRAJECTORY_POSES` poses is thinned: the newest half of the limit
is kept whole, and of the older poses every second one is dropped (the oldest one stays). Applied each
time the limit is passed, the old part's spacing doubles each round, so the trajectory keeps every
recent pose and ever sparser older ones (a multi-resolution path), and never holds more than the limit
(after thinning it holds about three quarters of it). Pure; O(n) for n poses.
"""

from __future__ import annotations

__all__ = ["MAX_TRAJECTORY_POSES", "thin_positions"]

#: Poses kept of a trajectory (about 70 bytes each as JSON rows: at most ~560 kB in a snapshot or map).
MAX_TRAJECTORY_POSES = 8_000


def thin_positions(n_poses: int, max_poses: int = MAX_TRAJECTORY_POSES) -> list[int]:
    """The positions (0 = oldest) to drop from a trajectory of ``n_poses`` poses kept in time order so
    that at most ``max_poses`` remain; empty when it fits. The newest ``max_poses // 2`` poses are never
    dropped; of the ones before them, those at odd positions are, repeatedly until the rest fits.
    ``max_poses`` must be at least 2. O(n_poses)."""
    if max_poses < 2:
        raise ValueError(f"max_poses must be at least 2, got {max_poses}")
    if n_poses <= max_poses:
        return []
    keep_new = max_poses // 2
    old = list(range(n_poses - keep_new))
    dropped: list[int] = []
    while len(old) + keep_new > max_poses:
        dropped.extend(old[1::2])
        old = old[0::2]
    return sorted(dropped)
