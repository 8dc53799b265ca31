"""Loop closure on the robot: the pose graph beside the step, its slow work on a worker thread.

:class:`OnlineGraphMapper` has the interface of :class:`~shared.pipeline.Pipeline` that the robot agent
uses (``step``, ``walls``, ``recent_centroids``, ``snapshot``, ``config``, ``reconfigure``, ``timing_ms``,
``pose``, ``version``), so the agent runs it in the pipeline's place. In the step it runs the front end and,
at a keyframe, adds the node with its sequential and skip edges (:class:`~shared.slam.mapper.GraphMapper`,
about a millisecond). Off the step's path, on one worker thread:

- the **loop search** of each new keyframe (correlative searches, tens of milliseconds), whose closures
  join the graph between two steps' graph updates, under the mapper's lock;
- after closures, a **rebuild of the shown map**: the scans kept so far (one each 10 cm or 5 degrees of
  motion, :data:`REDRAW_SPACING`) mapped again at their corrected poses by a fresh pipeline (as
  :meth:`GraphMapper.finish` does offline with every scan). It is swapped in between two steps, the scans
  kept meanwhile are caught up at their corrected poses, and from then on each step feeds it at the
  corrected pose. Walls drawn twice before the loop was closed come out once; the agent's next map version
  carries the changed and removed walls.

Until the first closure the shown map is the front end's own. A rebuild costs as much as mapping the kept
scans again (about 2 ms a scan on the simulated world, one kept in four at 0.4 m/s): after an hour of
driving about 15 s of the worker's time, and closures arriving meanwhile are taken by the next rebuild;
memory grows with the distance driven (a robot standing still keeps nothing), not with time.
Keyframe-anchored wall observations, re-placed without mapping the scans again, are the way to bound it
further (docs/loopclosure.md, "Not yet").

Thread safety: the step, the worker and the readers (``walls``, ``snapshot``) share the mapper under one
lock; the worker holds it only to read the graph's poses and to add edges, never while it searches or
rebuilds.
"""

from __future__ import annotations

import logging
import math
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from shared.errors import LinemapError, StateError
from shared.pipeline import MapSnapshot, Pipeline, PipelineConfig
from shared.pipeline.pipeline import MapState, StepResult
from shared.pipeline.state import MapperState
from shared.slam.mapper import GraphMapper
from shared.slam.onlinestate import graph_state, restore_graph
from shared.slam.settings import LoopClosureSettings
from shared.types import FloatArray, IntArray, Pose2D, Scan

__all__ = ["OnlineGraphMapper"]

log = logging.getLogger(__name__)

_REBUILD = -1  # the worker's job id for a rebuild (keyframe jobs are their index)
_STOP = -2
#: a rebuild hands over when at most this many scans are left to catch up (in the step, ~2 ms each)
_CATCH_UP_IN_STEP = 3
#: keyframes (0.5 m each by default) between the starts of two rebuilds of the shown map
REBUILD_EVERY_KEYFRAMES = 20
#: a redraw maps a scan each time the robot moved 10 cm or turned 5 degrees since the last one it kept (m,
#: rad): a wall is seen from nearly the same place by the scans between, and a robot standing still adds
#: nothing; on two-lap loop-block runs every 4th scan drew maps as good as every scan, in a quarter of the
#: time (every 12th lost small walls)
REDRAW_SPACING = (0.10, math.radians(5.0))


class OnlineGraphMapper:
    """The front end, the pose graph and the shown map, for a robot (module docstring).

    ``make_pipeline(config)`` builds a pipeline with the robot's laser offset; ``config`` is the first
    configuration; ``settings`` the loop closure's (default: ``config``'s, else the defaults).
    ``worker=False`` runs the search and the rebuild in the step (tests, replays that must be
    deterministic).

    ``redraw_spacing``: the scans kept for redraws (:data:`REDRAW_SPACING`; None: every one).

    ``front``: a pipeline that has mapped already (loop closure switched on while the robot runs). It goes
    on as the front end, the graph starts at its pose, and its map so far is the base every rebuild
    starts from: what was drawn before stays as drawn, and what is mapped from now on is corrected."""

    def __init__(
        self,
        make_pipeline: Callable[[PipelineConfig], Pipeline],
        config: PipelineConfig,
        settings: LoopClosureSettings | None = None,
        *,
        worker: bool = True,
        front: Pipeline | None = None,
        redraw_spacing: tuple[float, float] | None = REDRAW_SPACING,
    ) -> None:
        self._make = make_pipeline
        self._config = config
        settings = settings or config.loop_closure_settings()
        self._base: MapState | None = None
        if front is not None and (front.version or len(front.walls()[0])):  # mapped, or continues a map
            front.flush()
            self._base = front.map_state()
        self._mapper = GraphMapper(
            lambda: make_pipeline(self._config), settings, front=front, redraw_spacing=redraw_spacing
        )
        self._mapper.search_inline = False
        self._lock = threading.RLock()
        self._shown: Pipeline | None = None  # the rebuilt map, once a loop was closed
        self._pending: tuple[Pipeline, int] | None = None  # a rebuilt map and the scans it covers
        self._closed_since_rebuild = False
        self._rebuilt_at = -REBUILD_EVERY_KEYFRAMES  # keyframe count when the last rebuild began
        self._version = front.version if front is not None else 0
        self.rebuilds = 0
        self.redraw_ms: list[float] = []  # each redraw of the shown map, its catch-up included
        self.failure: str | None = None  # the worker's last error (the robot keeps mapping)
        self._cov: FloatArray | None = None  # pose_covariance's cache, valid for the graph at _cov_key
        self._cov_key: tuple[int, int, int] | None = None
        self._jobs: queue.Queue[int] = queue.Queue()
        self._idle = threading.Condition()
        self._outstanding = 0  # jobs submitted and not finished
        self._searches: set[int] = set()  # keyframes whose loop search is submitted and not finished
        self._rebuilding = False  # a rebuild is under way on the worker
        self._thread: threading.Thread | None = None
        if worker:
            self._thread = threading.Thread(target=self._work, name="loop-closure", daemon=True)
            self._thread.start()

    # ------------------------------------------------------------------ the step
    def step(self, scan: Scan, odometry: Pose2D | None = None) -> StepResult:
        """One scan: the front end, the graph's keyframes, the shown map; the pose is the corrected one."""
        with self._lock:
            self._swap_in()
            keyframes = len(self._mapper.keyframes)
            result = self._mapper.step(scan, odometry)
            if self._shown is not None:
                self._shown.step(scan, odometry, pose=result.pose)
            new_key = len(self._mapper.keyframes) > keyframes
        self._version += 1
        if new_key and self._mapper.settings.enabled:
            self._submit(len(self._mapper.keyframes) - 1)
        return StepResult(self._version, result.pose, result.icp_used, result.ran, result.step_ms)

    def flush(self) -> None:
        """Take in the closures not yet drawn (a rebuild now, in the step or on the worker, waited for)
        and run every pending batch of the shown map's stages."""
        if self._closed_since_rebuild:
            if self._thread is None:
                self._run(_REBUILD)
            else:
                self._enqueue(_REBUILD)
        self.wait_idle()
        with self._lock:
            self._swap_in()
            self._shown_or_front().flush()

    def _rebuild_due(self) -> bool:
        """Closures not drawn yet, and ``REBUILD_EVERY_KEYFRAMES`` keyframes since the last rebuild began:
        each rebuild maps every scan again, so they are spaced out (``flush`` takes the rest)."""
        return (
            self._closed_since_rebuild
            and len(self._mapper.keyframes) - self._rebuilt_at >= REBUILD_EVERY_KEYFRAMES
        )

    def _submit(self, job: int) -> None:
        if self._thread is None:
            self._run(job)
            if self._rebuild_due():
                self._run(_REBUILD)
            self._swap_in()
            return
        self._enqueue(job)

    def _enqueue(self, job: int) -> None:
        with self._idle:
            self._outstanding += 1
            if job >= 0:
                self._searches.add(job)
        self._jobs.put(job)

    def _swap_in(self) -> None:
        """Take a finished rebuild: catch it up on the scans stepped since its poses were read."""
        pending, self._pending = self._pending, None
        if pending is None:
            return
        rebuilt, covered = pending
        trajectory = self._mapper.trajectory()
        _replay(rebuilt, self._mapper.stepped()[covered:], trajectory)
        self._shown = rebuilt
        self.rebuilds += 1
        log.info("loop closure: map rebuilt from %d corrected poses", len(trajectory))

    # ------------------------------------------------------------------ the worker
    def _work(self) -> None:
        while True:
            job = self._jobs.get()
            if job == _STOP:
                return
            self._run(job)
            if job >= 0 and self._jobs.empty() and self._rebuild_due():
                self._run(_REBUILD)
            with self._idle:
                self._outstanding -= 1
                self._searches.discard(job)
                self._idle.notify_all()

    def _run(self, job: int) -> None:
        try:
            if job == _REBUILD:
                self._rebuild()
            else:
                self._search(job)
        except LinemapError as exc:
            self.failure = f"loop closure: {exc}"
            log.warning("%s; mapping goes on without it", self.failure)
        except Exception as exc:  # the worker must not die with the robot still mapping
            self.failure = f"loop closure failed: {type(exc).__name__}: {exc}"
            log.exception("loop closure failed; mapping goes on without it")

    def _search(self, k: int) -> None:
        matches = self._mapper.find_closures(k)
        if not matches:
            return
        with self._lock:
            if self._mapper.add_closures(k, matches):
                self._closed_since_rebuild = True

    def _rebuild(self) -> None:
        t0 = time.perf_counter()
        self._rebuilding = True
        try:
            self._redraw()
        finally:
            self._rebuilding = False
            self.redraw_ms.append((time.perf_counter() - t0) * 1e3)

    def _redraw(self) -> None:
        with self._lock:
            self._closed_since_rebuild = False
            self._rebuilt_at = len(self._mapper.keyframes)
            trajectory = self._mapper.trajectory()
            scans = list(self._mapper.stepped())
        rebuilt = self._make(self._config)
        if self._base is not None:
            rebuilt.seed_map(self._base)
        covered = 0
        while True:  # catch up here, not in the step: the robot went on while this ran
            _replay(rebuilt, scans[covered:], trajectory)
            covered = len(scans)
            with self._lock:
                if len(self._mapper.stepped()) - covered <= _CATCH_UP_IN_STEP:
                    self._pending = (rebuilt, covered)
                    return
                trajectory = self._mapper.trajectory()
                scans = list(self._mapper.stepped())

    def wait_idle(self, timeout_s: float | None = None) -> bool:
        """Block until the worker has no job left (tests, the end of a replay), then take a finished
        rebuild in; whether it got there within ``timeout_s``."""
        with self._idle:
            done = self._idle.wait_for(lambda: self._outstanding == 0, timeout_s)
        if done:
            with self._lock:
                self._swap_in()
        return done

    def close(self) -> None:
        """Stop the worker (what it was doing is dropped)."""
        if self._thread is not None:
            self._jobs.put(_STOP)
            self._thread.join(timeout=5.0)
            self._thread = None

    # ------------------------------------------------------------------ saved state
    def state(self) -> MapperState:
        """The learned state as data (:mod:`shared.slam.onlinestate`); a finished rebuild is taken in
        first. Holds the lock while it copies (O(graph + kept scans + map))."""
        with self._lock:
            self._swap_in()
            with self._idle:
                searches = sorted(self._searches)
            parts = {
                "mapper": self._mapper,
                "shown": self._shown,
                "base": self._base,
                "version": self._version,
                "closed": self._closed_since_rebuild or self._rebuilding,
                # a rebuild under way is lost with the process: the restored mapper starts it again now
                "rebuilt_at": -REBUILD_EVERY_KEYFRAMES if self._rebuilding else self._rebuilt_at,
                "rebuilds": self.rebuilds,
                "searches": searches,
            }
            return graph_state(self, parts)

    def restore(self, state: MapperState) -> None:
        """Go on from ``state`` (:meth:`state`), before the first step only (:class:`StateError`); loop
        searches that were pending are submitted again."""
        if self._version or self._mapper.keyframes:
            raise StateError("a graph mapper's state can be restored only before its first step")
        parts = restore_graph(self, state)
        with self._lock:
            self._mapper, self._shown, self._base = parts["mapper"], parts["shown"], parts["base"]
            self._version, self._rebuilt_at = int(parts["version"]), int(parts["rebuilt_at"])
            self._closed_since_rebuild, self.rebuilds = bool(parts["closed"]), int(parts["rebuilds"])
        for k in parts["searches"]:
            self._submit(int(k))
        if self._thread is not None and self._rebuild_due():
            self._enqueue(_REBUILD)

    # ------------------------------------------------------------------ the pipeline's interface
    def _shown_or_front(self) -> Pipeline:
        return self._shown if self._shown is not None else self._mapper.front

    @property
    def config(self) -> PipelineConfig:
        """The configuration in force."""
        return self._config

    def reconfigure(self, config: PipelineConfig) -> None:
        """Swap in a new configuration between steps (front end and shown map; a rebuild under way uses
        the old one for the scans it had); on any error the old one stays in force and the error
        propagates. The loop closure's settings come from ``config`` (``loop_closure`` None: the search
        stops, the graph and the map drawn so far stay); the robust kernel's width is the graph's from
        its start."""
        with self._lock:
            self._mapper.settings = config.loop_closure_settings() or replace(
                self._mapper.settings, enabled=False
            )
            self._mapper.front.reconfigure(config)
            if self._shown is not None:
                try:
                    self._shown.reconfigure(config)
                except Exception:
                    self._mapper.front.reconfigure(self._config)
                    raise
            self._config = config

    @property
    def version(self) -> int:
        """Increases with every step."""
        return self._version

    @property
    def pose(self) -> Pose2D:
        """The corrected robot pose now (world frame)."""
        with self._lock:
            return self._mapper.pose

    @property
    def settings(self) -> LoopClosureSettings:
        """The loop closure's settings in force."""
        return self._mapper.settings

    @property
    def optimise_ms(self) -> list[float]:
        """The time of each pose-graph optimisation so far (an iSAM2 update at every keyframe and after
        each batch of closures), ms."""
        return self._mapper.optimise_ms

    @property
    def closures(self) -> int:
        """Loop closures accepted so far."""
        return len(self._mapper.closures)

    def timing_ms(self) -> tuple[float, float]:
        """Median and 99th percentile of the front end's recent step times (ms)."""
        return self._mapper.front.timing_ms()

    def walls(self) -> tuple[IntArray, FloatArray]:
        """The shown map's walls: ids ``(W,)`` and end points ``(W, 4)`` (m)."""
        with self._lock:
            return self._shown_or_front().walls()

    def recent_centroids(self, limit: int) -> FloatArray:
        """The shown map's last ``limit`` centroids ``(C, 2)`` (m)."""
        with self._lock:
            return self._shown_or_front().recent_centroids(limit)

    def snapshot(self) -> MapSnapshot:
        """The shown map with the corrected trajectory and pose."""
        with self._lock:
            snap = self._shown_or_front().snapshot()
            trajectory = self._trajectory()
            pose = self._mapper.pose
        trajectory.setflags(write=False)
        return MapSnapshot(
            self._version, snap.stamp_s, snap.segments, snap.segment_ids, snap.centroids, pose, trajectory
        )

    def keyframe_rows(self) -> list[list[float]]:
        """The keyframes ``[keyframe_id, stamp_s, x_m, y_m, theta_rad]`` as corrected now. O(keyframes)."""
        with self._lock:
            return self._mapper.keyframe_rows()

    def closure_pairs(self) -> list[list[int]]:
        """The accepted loop closures ``[keyframe_id_a, keyframe_id_b]``. O(closures)."""
        with self._lock:
            return self._mapper.closure_pairs()

    def pose_covariance(self) -> FloatArray | None:
        """The covariance ``(3, 3)`` (world frame; m^2, m*rad, rad^2) of the newest keyframe, the pose
        graph's uncertainty of where the robot is (the motion since that keyframe is not in it); None before
        the first keyframe or when the solver cannot give it. Cached until the graph changes."""
        with self._lock:
            n = len(self._mapper.graph)
            key = (n, len(self._mapper.closures), len(self._mapper.optimise_ms))
            if n == 0:
                return None
            if self._cov_key != key:
                try:
                    self._cov = self._mapper.graph.covariance(n - 1)
                except LinemapError as exc:
                    log.debug("no pose covariance: %s", exc)
                    self._cov = None
                self._cov_key = key
            return self._cov

    def trajectory(self) -> FloatArray:
        """The corrected trajectory ``(N, 4)`` (stamp s, x m, y m, heading rad); with a ``front`` that had
        mapped before, its poses from then first, as they were."""
        with self._lock:
            return self._trajectory()

    def _trajectory(self) -> FloatArray:
        corrected = np.asarray(self._mapper.trajectory(), dtype=np.float64).reshape(-1, 4)
        if self._base is None or not self._base.trajectory:
            return corrected
        return np.vstack([np.asarray(self._base.trajectory, dtype=np.float64), corrected])


def _replay(pipeline: Pipeline, scans: list[tuple[int, Scan, Pose2D | None]], trajectory: FloatArray) -> None:
    """Map ``scans`` (step index, scan, odometry) at their corrected poses (``trajectory`` rows)."""
    for step, scan, odometry in scans:
        row = trajectory[step]
        pipeline.step(scan, odometry, pose=Pose2D(row[1], row[2], row[3]))
