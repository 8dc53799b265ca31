"""A pipeline with a bounded ``history`` (the agent's: a robot maps for days) keeps its memory and saved
state bounded whatever the run's length, and maps exactly as one that keeps everything: the same poses,
walls and recent centroids; only the old trajectory is thinned (by the rule the Robot DB and the server
apply) and old centroid batches dropped. A wall map's list of removed ids keeps the newest ones only."""

from __future__ import annotations

import itertools
from functools import cache

import numpy as np
import pytest

from robot_agent.sources import open_scans
from shared.errors import LinemapError
from shared.pipeline import Pipeline, PipelineConfig
from shared.pipeline.pipeline import KEPT_CENTROID_BATCHES
from shared.pipeline.wallmap import REMOVED_KEPT, WallMap
from shared.protocol.trajectory import thin_positions
from shared.sim import default_world, simulate_run
from shared.types import Pose2D, Scan

OFFSET = Pose2D(0.1, 0.0, 0.0)
HISTORY = 100


@cache
def _scans() -> tuple[Scan, ...]:
    return tuple(itertools.islice(simulate_run(default_world(), seed=4).scans, 500))


@cache
def _patrol() -> tuple[Scan, ...]:
    """Two laps out and back of the simulator's drive (about 2,000 scans)."""
    return tuple(open_scans("sim", seed=4, laps=2))


def test_a_bounded_history_maps_exactly_as_a_full_one_and_stays_bounded() -> None:
    full = Pipeline(PipelineConfig(), laser_offset=OFFSET)
    bounded = Pipeline(PipelineConfig(), laser_offset=OFFSET, history=HISTORY)
    sizes: dict[int, tuple[int, int]] = {}
    scans = _patrol()
    for i, scan in enumerate(scans, 1):
        assert full.step(scan).pose == bounded.step(scan).pose
        if i in (len(scans) // 2, len(scans)):
            sizes[i] = (len(bounded.state().to_bytes()), len(full.state().to_bytes()))
    for a, b in zip(full.walls(), bounded.walls(), strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(full.recent_centroids(200), bounded.recent_centroids(200))
    kept = bounded.snapshot().trajectory
    assert len(kept) <= HISTORY
    everything = full.snapshot().trajectory
    np.testing.assert_array_equal(kept[-HISTORY // 2 :], everything[-HISTORY // 2 :])  # the newest whole
    assert set(map(tuple, kept.tolist())) <= set(map(tuple, everything.tolist()))
    assert len(bounded._centroids) <= 2 * KEPT_CENTROID_BATCHES
    # doubling the run's length: the saved state grows by what the map gained (and the local maps and
    # centroid batches between two trims), not by the steps as a full history's does
    (bounded_half, full_half), (bounded_whole, full_whole) = sizes.values()
    assert bounded_whole - bounded_half < 0.3 * (full_whole - full_half), sizes


def test_the_trajectory_is_thinned_by_the_shared_rule() -> None:
    bounded = Pipeline(PipelineConfig(), laser_offset=OFFSET, history=HISTORY)
    stamps: list[float] = []
    for scan in _scans()[:300]:
        bounded.step(scan)
        stamps.append(scan.stamp_s)
        if len(stamps) > HISTORY:
            drop = set(thin_positions(len(stamps), HISTORY))
            stamps = [s for i, s in enumerate(stamps) if i not in drop]
    assert bounded.snapshot().trajectory[:, 0].tolist() == stamps


def test_a_bounded_history_survives_a_saved_state() -> None:
    bounded = Pipeline(PipelineConfig(), laser_offset=OFFSET, history=HISTORY)
    for scan in _scans()[:200]:
        bounded.step(scan)
    again = Pipeline(PipelineConfig(), laser_offset=OFFSET, history=HISTORY)
    again.restore(bounded.state())
    for scan in _scans()[200:300]:
        assert bounded.step(scan).pose == again.step(scan).pose
    assert len(again.snapshot().trajectory) <= HISTORY


def test_history_must_hold_two_poses() -> None:
    with pytest.raises(LinemapError, match="history"):
        Pipeline(history=1)


def test_a_wall_map_keeps_only_the_newest_removed_ids() -> None:
    m = WallMap()
    for k in range(3 * REMOVED_KEPT):  # each piece fuses into the first wall: its id is removed
        m.add_segments([[0.0, 0.0, 4.0, 0.0]] if k == 0 else [[0.0, 0.001, 4.0, 0.001]])
    assert REMOVED_KEPT <= len(m.removed) <= 2 * REMOVED_KEPT
    assert m.removed[-1] == 3 * REMOVED_KEPT - 1  # the newest kept
