"""The agent's mapping loop: reads scans from the source, steps the pipeline, records each step in the Robot
DB (its outbox), and between two steps lets the kernel supervisor apply control messages.

:class:`PipelineSlot` holds the pipeline in force (a :class:`~shared.pipeline.Pipeline`, or an
:class:`~shared.slam.OnlineGraphMapper` once loop closure is on), which the supervisor reconfigures between
steps; :class:`RecentScans` keeps the last scans for the dry runs of downloaded kernels (poller thread).
A step costs the pipeline's step plus O(walls) to find the changed walls; lengths in metres, times in s.

A full disk (the Robot DB cannot grow: :func:`shared.diskfull.disk_full_reason`) pauses recording: the
step already mapped is recorded again every ``DISK_RETRY_S`` until space returns, with the reason in the
status' ``last_error`` (the uploader reports it to the server even with nothing to upload); no scan is
mapped meanwhile (a replayed source goes on where it paused, a live sensor's scans of the pause are not
mapped), and nothing recorded before is lost.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import replace
from typing import Any

import numpy as np

from robot_agent.health import AgentStats
from robot_agent.resume import Checkpoints
from robot_agent.settings import AgentSettings
from robot_agent.sources import is_live, open_scans
from robot_agent.store import RobotDB, StepRecord
from shared.diskfull import disk_full_reason
from shared.pipeline import MapperState, Pipeline, PipelineConfig
from shared.pipeline.pipestate import PIPELINE_KIND
from shared.protocol import MAX_TRAJECTORY_POSES
from shared.slam import OnlineGraphMapper
from shared.slam.onlinestate import GRAPH_KIND
from shared.types import FloatArray, Pose2D, Scan

__all__ = ["DISK_RETRY_S", "MappingLoop", "PipelineSlot", "RecentScans"]

log = logging.getLogger(__name__)

#: how often a step is tried again while the Robot DB's disk is full (s)
DISK_RETRY_S = 1.0
#: how often a pause is reported again (the status' last_error clears after a healthy while otherwise)
DISK_REPORT_S = 20.0


class PipelineSlot:
    """The pipeline in force; empty until :meth:`start`. Used from the mapping thread only."""

    def __init__(self, laser_offset: Pose2D) -> None:
        self.laser_offset = laser_offset
        self._pipeline: Pipeline | OnlineGraphMapper | None = None

    def start(self, config: PipelineConfig) -> None:
        """Build the pipeline for ``config`` (with the pose graph if it has loop closure on)."""
        if config.loop_closure is not None:
            self._pipeline = self._graph(config)
        else:
            self._pipeline = self._make_pipeline(config)

    @property
    def pipeline(self) -> Pipeline | OnlineGraphMapper:
        assert self._pipeline is not None, "PipelineSlot.start was not called"
        return self._pipeline

    @property
    def config(self) -> PipelineConfig | None:
        """The configuration in force; None before :meth:`start`."""
        return self._pipeline.config if self._pipeline is not None else None

    def _make_pipeline(self, config: PipelineConfig) -> Pipeline:
        # a bounded history: the robot maps for days (docs/reliability/bounded.md)
        return Pipeline(config, laser_offset=self.laser_offset, history=MAX_TRAJECTORY_POSES)

    def _graph(self, config: PipelineConfig, front: Pipeline | None = None) -> OnlineGraphMapper:
        return OnlineGraphMapper(self._make_pipeline, config, front=front, history=MAX_TRAJECTORY_POSES)

    def reconfigure(self, config: PipelineConfig) -> None:
        """Swap ``config`` in between two steps. Loop closure switched on over the front end alone starts
        the pose graph here, at the pose the robot has, over the map drawn so far (which stays as drawn);
        switched off, the graph stays and stops searching (:class:`OnlineGraphMapper`)."""
        pipeline = self.pipeline
        if isinstance(pipeline, Pipeline) and config.loop_closure is not None:
            pipeline.reconfigure(config)  # raises with the old configuration kept
            graph = self._graph(config, pipeline)
            self._pipeline = graph
            log.info("loop closure switched on at step %d", graph.version)
            return
        pipeline.reconfigure(config)

    def continue_map(
        self, walls: dict[int, tuple[float, ...]], pose: Pose2D, odometry: Pose2D | None
    ) -> None:
        """Start from a map taken over from the server (before the first step): its ``walls`` by id, the
        robot at ``pose`` where odometry read ``odometry`` (:meth:`shared.pipeline.Pipeline.continue_map`).
        With loop closure the pose graph starts there, over those walls (as when it is switched on)."""
        config = self.config
        assert config is not None, "PipelineSlot.start was not called"
        ids = np.array(sorted(walls), dtype=np.int64)
        segments = np.array([walls[i] for i in ids], dtype=np.float64).reshape(-1, 4)
        front = self._make_pipeline(config)
        front.continue_map(ids, segments, pose, odometry)
        if isinstance(self._pipeline, OnlineGraphMapper):
            self.close()
            self._pipeline = self._graph(config, front)
        else:
            self._pipeline = front

    def restore(self, state: MapperState) -> None:
        """Go on from a saved ``state`` (before the first step). A front end's state under a configuration
        with loop closure starts the pose graph over it, and a graph's state under one without keeps the
        graph, which stops searching: as :meth:`reconfigure` does while running."""
        config = self.config
        assert config is not None, "PipelineSlot.start was not called"
        if state.kind == PIPELINE_KIND and isinstance(self._pipeline, OnlineGraphMapper):
            self.close()
            front = self._make_pipeline(config)
            front.restore(state)
            self._pipeline = self._graph(config, front)
        elif state.kind == GRAPH_KIND and isinstance(self._pipeline, Pipeline):
            lc = config.model_copy(update={"loop_closure": {}})
            graph = self._graph(lc)
            self._pipeline = graph
            graph.restore(state)
            graph.reconfigure(config)
        else:
            self.pipeline.restore(state)

    def close(self) -> None:
        if isinstance(self._pipeline, OnlineGraphMapper):
            self._pipeline.close()


class RecentScans:
    """The last ``size`` scans mapped, shared between the mapping thread and the poller. O(1) to add."""

    def __init__(self, size: int = 10) -> None:
        self._scans: deque[Scan] = deque(maxlen=size)
        self._lock = threading.Lock()

    def add(self, scan: Scan) -> None:
        with self._lock:
            self._scans.append(scan)

    def latest(self) -> list[Scan]:
        """The scans kept, oldest first."""
        with self._lock:
            return list(self._scans)


class MappingLoop:
    """Maps from ``settings.source`` into ``slot``'s pipeline. Collaborators: ``db`` (the Robot DB: each
    step's record, and where to resume after a restart), ``stats`` (``steps``), ``recent`` (scans for dry
    runs), ``between_steps`` (applies pending control messages), ``after_step`` (the kernels' probation and
    rollback), ``wake`` (set after each step recorded: the uploader has something to send). Built after
    ``slot`` started: it resumes the map recorded in ``db`` (:mod:`robot_agent.resume`)."""

    def __init__(
        self,
        settings: AgentSettings,
        slot: PipelineSlot,
        db: RobotDB,
        stats: AgentStats,
        recent: RecentScans,
        between_steps: Callable[[], None],
        after_step: Callable[[], None],
        wake: threading.Event,
    ) -> None:
        self.s = settings
        self.slot, self.db, self.stats, self.recent = slot, db, stats, recent
        self._between_steps, self._after_step, self._wake = between_steps, after_step, wake
        self._stepped: tuple[int, float] = (0, 0.0)
        # the mapping state saved with the steps: a restart goes on with the same map at the same pose
        self.checkpoints = Checkpoints(db, settings.checkpoint_steps, settings.checkpoint_s)
        resumed = self.checkpoints.resume(slot, recent)
        self._prev_walls: dict[int, tuple[float, ...]] = resumed.walls
        self._id_offset = resumed.id_offset
        self._continued = resumed.continued  # the server's map to start from, until the first step
        # a continued map's pose-graph keyframe ids follow the server's (robot_agent.store_adopt)
        self._keyframe_offset = int((db.continued_map() or {}).get("keyframe_offset", 0))
        # the pose graph's rows as last recorded (keyframe id -> row, closures count): a step records the
        # keyframes that are new or moved and the new closures; after a restart all are recorded once more
        # per keyframe (index from 0): the pose last recorded (x, y, theta), NaN until recorded
        self._sent_keyframes: FloatArray = np.full((0, 3), np.nan)
        self._prev_closures = 0
        # the graph's estimate last compared, and the first keyframe to compare while it stays the same
        # (OnlineGraphMapper.keyframe_changes): the step compares the keyframes that can have moved
        self._seen_estimate: object | None = None
        self._compare_from = 0
        if resumed.problem is not None:
            stats.last_error = resumed.problem

    def run(self, stop: threading.Event) -> None:
        """Map until the source ends, then (``stay``) keep applying messages until ``stop`` is set."""
        self._map(stop)
        while self.s.stay and not stop.is_set():  # the source ended: keep serving the link
            self._between_steps()
            stop.wait(0.05)

    def wall_time(self, version: int) -> float | None:
        """When the step of map ``version`` finished (Unix s), if it is the newest step; else None."""
        stepped_version, at = self._stepped
        return at if stepped_version == version else None

    def _map(self, stop: threading.Event) -> None:
        resume = int(self.db.get("source_index", 0) or 0)
        version = int(self.db.get("map_version", 0) or 0)
        own_pace = self.s.rate_hz is None  # the scans' own time stamps (logs) or 10 Hz (simulator)
        period = 0.1 if own_pace else (1.0 / self.s.rate_hz if self.s.rate_hz else None)
        next_at, last_stamp = time.monotonic(), None
        skipped_odometry: Pose2D | None = None
        # A replayable source (simulator, log) skips what was mapped before a restart; a live sensor
        # cannot be replayed, so its scans are all new and its count goes on from there.
        live = is_live(self.s.source)
        # a replayed source's last scan is known one scan ahead; a live sensor's scans are never held back
        scans = ((i, sc, False) for i, sc in self._scans(stop)) if live else _marking_last(self._scans(stop))
        for index, scan, last in scans:
            if live:
                index += resume
            if stop.is_set() or (self.s.max_steps is not None and self.stats.steps >= self.s.max_steps):
                return
            if index < resume:
                continue
            if self._continued is not None:
                if not live and scan.stamp_s <= self._continued.stamp_s:
                    skipped_odometry = scan.odometry  # a replayed source: mapped before, by the server's map
                    continue
                self._start_continued(skipped_odometry if not live else None)
            if own_pace and last_stamp is not None:
                period = min(max(scan.stamp_s - last_stamp, 0.0), 5.0)  # a gap in a log: wait at most 5 s
            last_stamp = scan.stamp_s
            if period is not None:
                stop.wait(max(0.0, next_at - time.monotonic()))
                next_at = max(next_at + period, time.monotonic() - period)
            self._between_steps()
            result = self.slot.pipeline.step(scan)
            if last and isinstance(self.slot.pipeline, OnlineGraphMapper):
                # the source's last scan: the loop-closure worker's searches still running are waited
                # for, so the last version carries every closure, keyframe move and the rebuilt walls
                # (later ones would reach no version: nothing is stepped after it)
                self.slot.pipeline.flush()
            self.recent.add(scan)
            version += 1
            journal, saved = self.checkpoints.after_step(self.slot, version, scan, self._id_offset)
            if not self._record_durably(
                self._record(version, index + 1, scan, result.pose), journal, saved, stop
            ):
                return
            self._stepped = (version, time.time())
            self.stats.steps += 1
            self._after_step()
            self._wake.set()

    def _start_continued(self, odometry: Pose2D | None) -> None:
        """The first step of a map taken over from the server: the pipeline starts from its walls and pose;
        ``odometry`` is where odometry read at that pose (a replayed source's scan at the server's last
        stamp), None for a live sensor (the robot is taken to be where the server's map left it)."""
        assert self._continued is not None
        self.slot.continue_map(self._prev_walls, self._continued.pose, odometry)
        log.info(
            "continuing the server's map: %d walls, from pose %s (odometry there %s)",
            len(self._prev_walls),
            self._continued.pose,
            "known" if odometry is not None else "not known",
        )
        self._continued = None

    def _record_durably(self, rec: StepRecord, journal: bytes, saved: Any, stop: threading.Event) -> bool:
        """Record the step; while the disk is full, report it and try again every ``DISK_RETRY_S``
        (module docstring). False when ``stop`` came first (the step is not recorded: a restart maps it
        again). Any other failure is raised."""
        paused_at: float | None = None
        told_at = 0.0
        while True:
            try:
                self.db.record_step(rec, journal, saved)
            except Exception as exc:
                reason = disk_full_reason(exc)
                if reason is None:
                    raise
                now = time.monotonic()
                if paused_at is None or now - told_at >= DISK_REPORT_S:  # kept reported while paused
                    message = (
                        f"the Robot DB's disk is full ({reason}): recording paused at map version "
                        f"{rec.version}, tried again every {DISK_RETRY_S:g} s until space returns"
                    )
                    if paused_at is None:
                        log.error("%s", message)
                    paused_at = paused_at or now
                    told_at = now
                    self.stats.last_error = message
                if stop.wait(DISK_RETRY_S):
                    return False
                continue
            if paused_at is not None:
                log.warning(
                    "space returned: recording resumed at map version %d after %.0f s paused",
                    rec.version,
                    time.monotonic() - paused_at,
                )
            return True

    def _scans(self, stop: threading.Event) -> Iterator[tuple[int, Scan]]:
        if is_live(self.s.source):
            scans = open_scans(self.s.source, encoders=self.s.encoders, stop=stop)
        else:
            scans = open_scans(self.s.source, seed=self.s.seed, laps=self.s.laps, encoders=self.s.encoders)
        yield from enumerate(scans)

    def _record(self, version: int, source_index: int, scan: Scan, pose: Any) -> StepRecord:
        pipeline = self.slot.pipeline
        ids, segments = pipeline.walls()
        now = {
            int(i) + self._id_offset: tuple(float(v) for v in seg)
            for i, seg in zip(ids, segments, strict=True)
        }
        changed = [[float(i), *seg] for i, seg in now.items() if self._prev_walls.get(i) != seg]
        removed = [i for i in self._prev_walls if i not in now]
        self._prev_walls = now
        cents = pipeline.recent_centroids(200).tolist()
        rec = StepRecord(
            version,
            scan.stamp_s,
            source_index,
            changed,
            removed,
            [scan.stamp_s, pose.x_m, pose.y_m, pose.theta_rad],
            cents,
        )
        if isinstance(pipeline, OnlineGraphMapper):
            return self._with_graph(rec, pipeline)
        return rec

    def _with_graph(self, rec: StepRecord, graph: OnlineGraphMapper) -> StepRecord:
        """``rec`` with the pose graph's rows: the keyframes that are new or moved since the last step
        (a loop closure moves many: the correction goes out as these), the new loop closures, the
        covariance. O(keyframes) vectorised after an optimisation moved the graph's estimate, else
        O(new keyframes) (:meth:`OnlineGraphMapper.keyframe_changes`), + O(new closures).

        A keyframe this step made goes out first at the pose this step records: the loop-closure worker
        may have moved it between the step and this read, and a first row off its own trajectory pose
        would stay off (a correction moves both by the same transform). The move goes out with the next
        step, as any keyframe's, and moves the trajectory with it."""
        stamp = rec.pose[0]
        off = self._keyframe_offset
        # [id, stamp, x, y, theta] of ids first..K-1: those that can have changed since the last step
        self._seen_estimate, first, rows = graph.keyframe_changes(self._seen_estimate, self._compare_from)
        n = first + len(rows)
        rows[:, 0] += off
        sent = self._sent_keyframes
        if len(sent) < n:  # keyframes never sent: NaN
            sent = np.vstack([sent, np.full((max(n, 2 * len(sent)) - len(sent), 3), np.nan)])
            self._sent_keyframes = sent
        prev = sent[first:n]
        unsent = np.isnan(prev[:, 0])
        at_step = (rows[:, 1] == stamp) & unsent
        rows[at_step, 2:] = rec.pose[1:]
        # a row recorded at the step's pose is compared with the estimate again next step
        self._compare_from = first + int(np.argmax(at_step)) if at_step.any() else n
        turn = np.abs(np.remainder(rows[:, 4] - prev[:, 2] + math.pi, math.tau) - math.pi)
        moved = (
            unsent
            | (np.abs(rows[:, 2] - prev[:, 0]) > _KEYFRAME_MOVED_M)
            | (np.abs(rows[:, 3] - prev[:, 1]) > _KEYFRAME_MOVED_M)
            | (turn > _KEYFRAME_MOVED_RAD)
        )
        prev[moved] = rows[moved, 2:]
        new_pairs = [[a + off, b + off] for a, b in graph.closure_pairs(self._prev_closures)]
        self._prev_closures += len(new_pairs)
        cov = graph.pose_covariance()
        return replace(
            rec,
            keyframes=rows[moved].tolist(),
            loop_closures=new_pairs,
            pose_covariance=None if cov is None else cov.tolist(),
            graph=True,
        )


#: a keyframe is recorded again when it moved more than this (m, rad): iSAM2 nudges recent keyframes at each
#: update by less, which no map drawn at centimetres shows; sending each nudge made a third of the steps
#: rewrite poses in the Robot DB (the agent's record 25 ms a step slower on loop-block)
_KEYFRAME_MOVED_M, _KEYFRAME_MOVED_RAD = 1e-3, 1e-3


def _marking_last(items: Iterator[tuple[int, Scan]]) -> Iterator[tuple[int, Scan, bool]]:
    """``items`` with a flag that is True on the last one (one item read ahead: the last is known only
    when the source ends). O(1) per item."""
    held: tuple[int, Scan] | None = None
    for item in items:
        if held is not None:
            yield (*held, False)
        held = item
    if held is not None:
        yield (*held, True)
