"""The agent's checkpoints over a real Robot DB file: a journaled scan reads back exactly; a restart
restores the saved state and re-steps the journal; a damaged state is an error that says so and a new map
starts whose first version removes the walls recorded before."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_agent.health import AgentStats
from robot_agent.journal import scan_from_bytes, scan_to_bytes
from robot_agent.mapping import PipelineSlot, RecentScans
from robot_agent.resume import Checkpoints
from robot_agent.store import RobotDB, SavedState, StepRecord
from shared.errors import StateError
from shared.pipeline import PipelineConfig
from shared.sim import default_world, simulate_run
from shared.slam import OnlineGraphMapper
from shared.types import Pose2D, Scan

SCANS = list(itertools.islice(simulate_run(default_world(), seed=1).scans, 30))


@settings(max_examples=50, deadline=None)
@given(
    ranges=st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=1, max_size=50),
    stamp=st.floats(-1e9, 1e9),
    odo=st.one_of(st.none(), st.tuples(*(st.floats(-1e6, 1e6),) * 3)),
    with_intensities=st.booleans(),
)
def test_a_journaled_scan_reads_back_exactly(ranges, stamp, odo, with_intensities) -> None:  # type: ignore[no-untyped-def]
    scan = Scan(
        stamp,
        -1.5,
        0.01,
        0.02,
        5.6,
        np.asarray(ranges),
        np.arange(len(ranges), dtype=np.float64) if with_intensities else None,
        None if odo is None else Pose2D(*odo),
    )
    back = scan_from_bytes(scan_to_bytes(scan))
    assert back.stamp_s == scan.stamp_s and back.odometry == scan.odometry
    np.testing.assert_array_equal(back.ranges_m, scan.ranges_m)
    if with_intensities:
        np.testing.assert_array_equal(back.intensities, scan.intensities)


def test_a_truncated_journaled_scan_is_refused() -> None:
    with pytest.raises(StateError, match="bytes of beams: expected"):
        scan_from_bytes(scan_to_bytes(SCANS[0])[:-8])


def _map(db: RobotDB, slot: PipelineSlot, ckpt: Checkpoints, scans: list[Scan], offset: int = 0) -> None:
    version = int(db.get("map_version", 0) or 0)
    prev = {int(w[0]): tuple(w[1:]) for w in db.walls()}
    for scan in scans:
        result = slot.pipeline.step(scan)
        version += 1
        ids, segs = slot.pipeline.walls()
        now = {int(i) + offset: tuple(float(v) for v in s) for i, s in zip(ids, segs, strict=True)}
        changed = [[float(i), *s] for i, s in now.items() if prev.get(i) != s]
        removed = [i for i in prev if i not in now]
        prev = now
        pose = result.pose
        rec = StepRecord(
            version, scan.stamp_s, version, changed, removed, [scan.stamp_s, *pose.as_tuple()], []
        )
        db.record_step(rec, *ckpt.after_step(slot, version, scan, offset))


def _slot() -> PipelineSlot:
    slot = PipelineSlot(Pose2D())
    slot.start(PipelineConfig())
    return slot


def test_a_restart_restores_the_state_and_re_steps_the_journal(tmp_path: Path) -> None:
    db = RobotDB(tmp_path / "robot.db")
    slot = _slot()
    _map(db, slot, Checkpoints(db, every_steps=8, every_s=1e9, background=False), SCANS)
    assert db.saved_state() is not None and db.saved_state().version == 25  # type: ignore[union-attr]
    assert [v for v, _ in db.journal(0)] == [26, 27, 28, 29, 30]
    again = _slot()
    resumed = Checkpoints(db, background=False).resume(again, RecentScans())
    assert resumed.problem is None and resumed.replayed == 5 and resumed.id_offset == 0
    assert again.pipeline.pose == slot.pipeline.pose
    np.testing.assert_array_equal(again.pipeline.walls()[1], slot.pipeline.walls()[1])


def test_a_damaged_state_starts_a_new_map_that_removes_the_old_walls(tmp_path: Path) -> None:
    db = RobotDB(tmp_path / "robot.db")
    _map(db, _slot(), Checkpoints(db, every_steps=8, every_s=1e9, background=False), SCANS)
    saved = db.saved_state()
    assert saved is not None
    old_walls = [int(w[0]) for w in db.walls()]
    assert old_walls
    damaged = SavedState(saved.version, saved.kind, saved.format, saved.id_offset, saved.state[:100])
    with db.tx() as s:
        from robot_agent.store_resume import write_resume

        write_resume(s, saved.version, None, damaged)
    stats = AgentStats()
    slot = _slot()
    resumed = Checkpoints(db, background=False).resume(slot, RecentScans())
    assert resumed.problem is not None
    assert "the stored mapping state of version 25 did not load" in resumed.problem
    assert "a new map starts at version 31" in resumed.problem
    assert slot.pipeline.version == 0 and db.saved_state() is None and db.journal(0) == []
    assert resumed.id_offset == max(old_walls) + 1
    stats.last_error = resumed.problem
    assert "did not load" in (stats.errors.status() or "")
    _map(db, slot, Checkpoints(db, background=False), SCANS[:1], offset=resumed.id_offset)
    assert all(int(w[0]) > max(old_walls) for w in db.walls()), "the old walls are gone"


def test_a_state_made_in_the_background_goes_with_a_later_step(tmp_path: Path) -> None:
    db = RobotDB(tmp_path / "robot.db")
    slot = _slot()
    ckpt = Checkpoints(db, every_steps=8, every_s=1e9)
    try:
        _map(db, slot, ckpt, SCANS[:1])
        first = db.saved_state()
        assert first is not None and first.version == 1, "the first state after a start is made in the step"
        _map(db, slot, ckpt, SCANS[1:20])
        if ckpt._pending is not None:
            ckpt._pending.result()  # its bytes ready: the next step records it
        _map(db, slot, ckpt, SCANS[20:22])
        saved = db.saved_state()
        assert saved is not None and 9 <= saved.version < 22
        kept = [v for v, _ in db.journal(0)]
        assert kept == list(range(saved.version + 1, 23)), "the steps after the state stay journaled"
    finally:
        ckpt.close()
    again = _slot()
    resumed = Checkpoints(db, background=False).resume(again, RecentScans())
    assert resumed.problem is None and resumed.replayed == 22 - saved.version
    assert again.pipeline.pose == slot.pipeline.pose
    np.testing.assert_array_equal(again.pipeline.walls()[1], slot.pipeline.walls()[1])


@pytest.mark.parametrize("before_lc", [False, True])
def test_loop_closure_switched_at_a_restart_keeps_the_map(tmp_path: Path, before_lc: bool) -> None:
    """A restart with loop closure switched on over a front end's state starts the graph over it; switched
    off over a graph's state, the graph stays (and stops searching): the pose and walls go on either way."""
    db = RobotDB(tmp_path / "robot.db")
    lc, plain = PipelineConfig.parse({"loop_closure": {}}), PipelineConfig()
    slot = PipelineSlot(Pose2D())
    slot.start(lc if before_lc else plain)
    try:
        _map(db, slot, Checkpoints(db, every_steps=8, every_s=1e9, background=False), SCANS)
        again = PipelineSlot(Pose2D())
        again.start(plain if before_lc else lc)
        try:
            resumed = Checkpoints(db, background=False).resume(again, RecentScans())
            assert resumed.problem is None
            assert isinstance(again.pipeline, OnlineGraphMapper)
            assert again.config == (plain if before_lc else lc)
            a, b = again.pipeline.pose, slot.pipeline.pose  # the graph composes poses: the last bits differ
            assert np.allclose(a.as_tuple(), b.as_tuple(), atol=1e-6)
            np.testing.assert_allclose(again.pipeline.walls()[1], slot.pipeline.walls()[1], atol=0.01)
        finally:
            again.close()
    finally:
        slot.close()
