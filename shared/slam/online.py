"""Loop closure on the robot: the pose graph beside the step, its slow work on a worker thread.

:class:`OnlineGraphMapper` has the interface of :class:`~shared.pipeline.Pipeline` that the robot agent
uses (``step``, ``walls``, ``recent_centroids``, ``snapshot``, ``config``, ``reconfigure``, ``timing_ms``,
``pose``, ``version``), so the agent runs it in the pipeline's place. In the step it runs the front end and,
at a keyframe, adds the node with its sequential and skip edges (:class:`~shared.slam.mapper.GraphMapper`,
about a millisecond). Off the step's path, on two worker threads (one for searches, one for rebuilds, so a
search due at a step never waits behind a rebuild):

- the **loop search** of each new keyframe (correlative searches, tens of milliseconds) under the graph's
  estimate when the keyframe was added; its closures join the graph at the step
  :data:`SEARCH_LAG_STEPS` later (waited for if the worker is late, which at 10 Hz it is not);
- after closures, a **rebuild of the shown map**: the scans kept so far (one each 10 cm or 5 degrees of
  motion, :data:`REDRAW_SPACING`) mapped again at their corrected poses, under the graph as it was when
  the rebuild began, by a fresh pipeline (as :meth:`GraphMapper.finish` does offline with every scan).
  It is swapped in between two steps once it has also taken what the shown map took meanwhile (each
  scan at the corrected pose of its step), and from then on each step feeds it at the corrected pose.
  Walls drawn twice before the loop was closed come out once; the agent's next map version carries the
  changed and removed walls.

**The same map whatever the timing.** Every job's input is taken in a step and its result enters at a
fixed step (a search's) or gives the same map whenever it enters (a rebuild's), so the worker's speed
changes when a map version shows a rebuild, never the graph or the map it converges to: a replay maps the
same every time, in the step (``worker=False``) or on the worker, and a restored mapper (pending jobs are
kept as their inputs) goes on as an uninterrupted one would, to within the rebuilt solver's
relinearisation.

Until the first closure the shown map is the front end's own. A rebuild costs as much as mapping the kept
scans again (about 2 ms a scan on the simulated world, one kept in four at 0.4 m/s): after an hour of
driving about 15 s of the worker's time without places; a rebuild begun while one is under way supersedes
it. A building driven again holds one keyframe scan and three kept scans per place
(:mod:`shared.slam.places`), so the scans held and a rebuild's time grow with the places visited, not
with the distance driven; the graph's nodes and edges (a few hundred bytes a keyframe) still do, and a
robot standing still adds nothing.

Thread safety: the step and the readers (``walls``, ``snapshot``) share the mapper under one lock; the
worker never takes it: it reads only its job's input and the append-only keyframes, steps and kept scans.
"""

from __future__ import annotations

import logging
import math
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from shared.errors import LinemapError, StateError
from shared.pipeline import MapSnapshot, Pipeline, PipelineConfig
from shared.pipeline.pipeline import MapState, StepResult
from shared.pipeline.state import MapperState
from shared.slam.closure import LoopMatch
from shared.slam.mapper import GraphMapper
from shared.slam.onlinestate import graph_state, restore_graph
from shared.slam.settings import LoopClosureSettings
from shared.types import FloatArray, IntArray, Pose2D, Scan

__all__ = ["OnlineGraphMapper"]

log = logging.getLogger(__name__)

#: a keyframe's loop closures join the graph at the step this many steps after the one that made the
#: keyframe (1 s at 10 Hz; a search takes tens of milliseconds), waited for if the worker is late: the
#: graph then takes every closure at the same step whatever the worker's timing (module docstring)
SEARCH_LAG_STEPS = 10
#: a finished rebuild is handed to the step once at most this many of the scans stepped meanwhile are
#: left for the step to map into it (~2 ms each); the worker maps the rest
_CATCH_UP_IN_STEP = 3
#: keyframes (0.5 m each by default) between the starts of two rebuilds of the shown map
REBUILD_EVERY_KEYFRAMES = 20
#: a redraw maps a scan each time the robot moved 10 cm or turned 5 degrees since the last one it kept (m,
#: rad): a wall is seen from nearly the same place by the scans between, and a robot standing still adds
#: nothing; on two-lap loop-block runs every 4th scan drew maps as good as every scan, in a quarter of the
#: time (every 12th lost small walls)
REDRAW_SPACING = (0.10, math.radians(5.0))


@dataclass(slots=True)
class _Search:
    """The loop search of keyframe ``k``: the graph's estimate and the keyframes retired when ``k`` was
    added (its whole input), the version at whose step its closures join the graph, and its result once
    searched."""

    k: int
    due: int
    estimate: FloatArray
    held: int  # keyframes retired when it began (shared.slam.places): it reads only those held then
    closures: int  # closures accepted when it began: they alone narrow its windows (shared.slam.window)
    matches: list[LoopMatch] | None = None


@dataclass(slots=True)
class _Redraw:
    """A rebuild of the shown map begun after the step of version ``at``: the kept scans up to then
    (``kept``) held then (``held``: kept scans retired then) at the graph's ``estimate`` then; ``since`` holds
    what the shown map took after ``at`` (scan, odometry, corrected pose), which the rebuilt map takes too
    before it is shown."""

    at: int
    estimate: FloatArray
    kept: int
    held: int
    since: list[tuple[Scan, Pose2D | None, Pose2D]] = field(default_factory=list)
    result: Pipeline | None = None
    caught_up: int = 0  # how many of ``since`` the worker has stepped into ``result``
    done: bool = False
    started: bool = False
    dropped: bool = False  # a later rebuild superseded it before it started


class OnlineGraphMapper:
    """The front end, the pose graph and the shown map, for a robot (module docstring).

    ``make_pipeline(config)`` builds a pipeline with the robot's laser offset; ``config`` is the first
    configuration; ``settings`` the loop closure's (default: ``config``'s, else the defaults).
    ``worker=False`` runs the search and the rebuild in the step (tests; the results are the same).

    ``redraw_spacing``: the scans kept for redraws (:data:`REDRAW_SPACING`; None: every one).
    ``history``: the trajectory's poses kept at most (the agent's bound; None: every one).
    ``places``: a building driven again holds one keyframe scan and three kept scans per place
    (:mod:`shared.slam.places`; False: every one, growing with the distance driven).

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
        history: int | None = None,
        places: bool = True,
    ) -> None:
        self._make = make_pipeline
        self._config = config
        settings = settings or config.loop_closure_settings()
        self._base: MapState | None = None
        if front is not None and (front.version or len(front.walls()[0])):  # mapped, or continues a map
            front.flush()
            self._base = front.map_state()
        self._mapper = GraphMapper(
            lambda: make_pipeline(self._config),
            settings,
            front=front,
            redraw_spacing=redraw_spacing,
            history=history,
            places=places,
        )
        self._mapper.search_inline = False
        self._lock = threading.RLock()
        self._shown: Pipeline | None = None  # the rebuilt map, once a loop was closed
        self._searches: list[_Search] = []  # submitted, not joined yet, in keyframe order
        self._redraws: list[_Redraw] = []  # submitted, not shown yet, oldest first
        self._closed_since_rebuild = False
        self._rebuilt_at = -REBUILD_EVERY_KEYFRAMES  # keyframe count when the last rebuild began
        self._version = front.version if front is not None else 0
        self.rebuilds = 0
        self.redraw_ms: list[float] = []  # each redraw of the shown map on the worker
        self.failure: str | None = None  # the worker's last error (the robot keeps mapping)
        self._cov: FloatArray | None = None  # pose_covariance's cache, valid for the graph at _cov_key
        self._cov_key: tuple[int, int, int] | None = None
        # searches and rebuilds on a thread each: a search due at a step never waits behind a rebuild,
        # which maps every kept scan again (seconds after an hour of driving)
        self._searches_q: queue.Queue[_Search | _Redraw | None] = queue.Queue()
        self._redraws_q: queue.Queue[_Search | _Redraw | None] = queue.Queue()
        self._idle = threading.Condition()
        self._outstanding = 0  # jobs submitted and not finished
        self._thread: threading.Thread | None = None  # the search thread (None: in the step)
        self._redraw_thread: threading.Thread | None = None
        self._closing = False
        if worker:
            self._thread = threading.Thread(
                target=self._work, args=(self._searches_q,), name="loop-search", daemon=True
            )
            self._redraw_thread = threading.Thread(
                target=self._work, args=(self._redraws_q,), name="loop-redraw", daemon=True
            )
            self._thread.start()
            self._redraw_thread.start()

    # ------------------------------------------------------------------ the step
    def step(self, scan: Scan, odometry: Pose2D | None = None) -> StepResult:
        """One scan: the closures due join the graph, then the front end, the graph's keyframes and the
        shown map; the pose is the corrected one."""
        with self._lock:
            self._join_searches(self._version + 1)
            self._swap_in()
            keyframes = len(self._mapper.keyframes)
            result = self._mapper.step(scan, odometry)
            if self._shown is not None:
                self._shown.step(scan, odometry, pose=result.pose)
            for redraw in self._redraws:
                redraw.since.append((scan, odometry, result.pose))
            self._version += 1
            if len(self._mapper.keyframes) > keyframes and self._mapper.settings.enabled:
                k = len(self._mapper.keyframes) - 1
                estimate = self._mapper.graph.pose_array()
                retired = self._mapper.places.keyframes_retired
                closures = len(self._mapper.closures)
                self._search(_Search(k, self._version + SEARCH_LAG_STEPS, estimate, retired, closures))
            if self._rebuild_due():
                self._begin_redraw()
            if self._thread is None:
                self._swap_in()
            self._free_retired()
        return StepResult(self._version, result.pose, result.icp_used, result.ran, result.step_ms)

    def flush(self) -> None:
        """Join every pending search's closures now (waited for), draw the map again if they closed a
        loop (waited for), and run every pending batch of the shown map's stages."""
        with self._lock:
            self._join_searches(None)
            if self._closed_since_rebuild:
                self._begin_redraw()
            self._wait_redraws()
            self._swap_in()
            self._shown_or_front().flush()

    def _rebuild_due(self) -> bool:
        """Closures not drawn yet, and ``REBUILD_EVERY_KEYFRAMES`` keyframes since the last rebuild began:
        each rebuild maps every scan again, so they are spaced out (``flush`` takes the rest)."""
        return (
            self._closed_since_rebuild
            and len(self._mapper.keyframes) - self._rebuilt_at >= REBUILD_EVERY_KEYFRAMES
        )

    def _search(self, job: _Search) -> None:
        self._searches.append(job)
        self._submit(job)

    def _join_searches(self, version: int | None) -> None:
        """Join the closures of the searches due by ``version`` (None: all), in keyframe order, waiting for
        those the worker has not finished. Under the lock (the worker never takes it)."""
        while self._searches and (version is None or self._searches[0].due <= version):
            job = self._searches.pop(0)
            if job.matches is None:
                with self._idle:
                    self._idle.wait_for(lambda job=job: job.matches is not None)  # type: ignore[misc]
            if job.matches and self._mapper.add_closures(job.k, job.matches):
                self._closed_since_rebuild = True
            self._mapper.retire_places(job.k)

    def _free_retired(self) -> None:
        """Free the data of what was retired before every pending job began (:mod:`shared.slam.places`):
        when this runs changes the state's size, never what a job reads."""
        places = self._mapper.places
        keyframes = min((j.held for j in self._searches), default=places.keyframes_retired)
        scans = min((r.held for r in self._redraws), default=places.scans_retired)
        self._mapper.free_retired(keyframes, scans)

    def _begin_redraw(self) -> None:
        """Start a rebuild of the shown map from the graph as it is now; earlier ones that have not
        started are superseded (one under way finishes and is shown, so a slow worker still shows some)."""
        self._closed_since_rebuild = False
        self._rebuilt_at = len(self._mapper.keyframes)
        for older in self._redraws:
            older.dropped = older.dropped or not older.started
        mapper = self._mapper
        job = _Redraw(
            self._version, mapper.graph.pose_array(), len(mapper.stepped()), mapper.places.scans_retired
        )
        self._redraws.append(job)
        self._submit(job)

    def _wait_redraws(self) -> None:
        with self._idle:
            self._idle.wait_for(lambda: all(r.done for r in self._redraws))

    def _submit(self, job: _Search | _Redraw) -> None:
        if self._thread is None:
            self._run(job)
            return
        with self._idle:
            self._outstanding += 1
        (self._redraws_q if isinstance(job, _Redraw) else self._searches_q).put(job)

    def _swap_in(self) -> None:
        """Show the latest finished rebuild, once it took what the shown map took since it began: the
        same map whenever it is swapped in."""
        done = [i for i, r in enumerate(self._redraws) if r.done]
        if not done:
            return
        job = self._redraws[done[-1]]
        del self._redraws[: done[-1] + 1]
        if job.result is None:  # failed (the worker said why) or superseded
            return
        for scan, odometry, pose in job.since[job.caught_up :]:
            job.result.step(scan, odometry, pose=pose)
        self._shown = job.result
        self.rebuilds += 1
        log.info("loop closure: map rebuilt from the graph of version %d", job.at)

    # ------------------------------------------------------------------ the worker
    def _work(self, jobs: queue.Queue[_Search | _Redraw | None]) -> None:
        while True:
            job = jobs.get()
            if job is None:
                return
            self._run(job)
            with self._idle:
                self._outstanding -= 1
                self._idle.notify_all()

    def _run(self, job: _Search | _Redraw) -> None:
        try:
            if isinstance(job, _Redraw):
                self._redraw(job)
            else:
                job.matches = self._mapper.find_closures(job.k, job.estimate, job.held, job.closures)
        except LinemapError as exc:
            self.failure = f"loop closure: {exc}"
            log.warning("%s; mapping goes on without it", self.failure)
        except Exception as exc:  # the worker must not die with the robot still mapping
            self.failure = f"loop closure failed: {type(exc).__name__}: {exc}"
            log.exception("loop closure failed; mapping goes on without it")
        finally:
            if isinstance(job, _Redraw):
                job.done = True
            elif job.matches is None:
                job.matches = []

    def _redraw(self, job: _Redraw) -> None:
        """Map the kept scans again at their poses under ``job.estimate`` (nothing the step changes is
        read but the append-only scans, steps and keyframes, up to ``job.kept``)."""
        if job.dropped:
            return
        job.started = True
        t0 = time.perf_counter()
        rebuilt = self._make(self._config)
        if self._base is not None:
            rebuilt.seed_map(self._base)
        held = self._mapper.places.scans_held(job.held)
        for i, (_step, scan, odometry) in enumerate(self._mapper.stepped()[: job.kept]):
            if self._closing:
                return
            if held[i] and scan is not None:  # held for this job: never freed while it is pending
                rebuilt.step(scan, odometry, pose=self._mapper.kept_pose(i, job.estimate))
        while not self._closing:  # catch up here, not in the step, until a few scans are left
            upto = len(job.since)
            if upto - job.caught_up <= _CATCH_UP_IN_STEP:
                break
            for scan, odometry, pose in job.since[job.caught_up : upto]:
                rebuilt.step(scan, odometry, pose=pose)
            job.caught_up = upto
        job.result = rebuilt
        self.redraw_ms.append((time.perf_counter() - t0) * 1e3)

    def wait_idle(self, timeout_s: float | None = None) -> bool:
        """Block until the worker has no job left (tests, the end of a replay), then take a finished
        rebuild in; whether it got there within ``timeout_s``. Closures join at their step or ``flush``."""
        with self._idle:
            done = self._idle.wait_for(lambda: self._outstanding == 0, timeout_s)
        if done:
            with self._lock:
                self._swap_in()
        return done

    def close(self) -> None:
        """Stop the worker (what it was doing is dropped)."""
        if self._thread is not None and self._redraw_thread is not None:
            self._closing = True
            self._searches_q.put(None)
            self._redraws_q.put(None)
            self._thread.join(timeout=5.0)
            self._redraw_thread.join(timeout=5.0)
            self._thread = self._redraw_thread = None

    # ------------------------------------------------------------------ saved state
    def state(self) -> MapperState:
        """The learned state as data (:mod:`shared.slam.onlinestate`); a finished rebuild is taken in
        first, the pending searches and the latest rebuild not shown yet are kept as their inputs (and
        results, where done). Holds the lock while it copies (O(graph + kept scans + map))."""
        with self._lock:
            self._swap_in()
            redraw = self._redraws[-1] if self._redraws else None
            parts = {
                "mapper": self._mapper,
                "shown": self._shown,
                "base": self._base,
                "version": self._version,
                "closed": self._closed_since_rebuild,
                "rebuilt_at": self._rebuilt_at,
                "rebuilds": self.rebuilds,
                "searches": [
                    (j.k, j.due, j.estimate, j.held, j.closures, j.matches) for j in self._searches
                ],
                "redraw": None
                if redraw is None
                else (redraw.at, redraw.estimate, redraw.kept, redraw.held, redraw.since),
            }
            return graph_state(self, parts)

    def restore(self, state: MapperState) -> None:
        """Go on from ``state`` (:meth:`state`), before the first step only (:class:`StateError`); the
        searches and the rebuild that were pending are submitted again with their saved inputs, so they
        give what they would have given."""
        if self._version or self._mapper.keyframes:
            raise StateError("a graph mapper's state can be restored only before its first step")
        parts = restore_graph(self, state)
        with self._lock:
            self._mapper, self._shown, self._base = parts["mapper"], parts["shown"], parts["base"]
            self._version, self._rebuilt_at = int(parts["version"]), int(parts["rebuilt_at"])
            self._closed_since_rebuild, self.rebuilds = bool(parts["closed"]), int(parts["rebuilds"])
            for k, due, estimate, held, closures, matches in parts["searches"]:
                job = _Search(int(k), int(due), estimate, int(held), int(closures), matches)
                self._searches.append(job)
                if matches is None:
                    self._submit(job)
            if parts["redraw"] is not None:
                at, estimate, kept, held, since = parts["redraw"]
                redraw = _Redraw(int(at), estimate, int(kept), int(held), list(since))
                self._redraws.append(redraw)
                self._submit(redraw)

    # ------------------------------------------------------------------ the pipeline's interface
    def _shown_or_front(self) -> Pipeline:
        return self._shown if self._shown is not None else self._mapper.front

    @property
    def config(self) -> PipelineConfig:
        """The configuration in force."""
        return self._config

    def reconfigure(self, config: PipelineConfig) -> None:
        """Swap in a new configuration between steps (front end and shown map; a rebuild under way is
        finished and shown first, so each is drawn under one configuration); on any error the old one
        stays in force and the error propagates. The loop closure's settings come from ``config``
        (``loop_closure`` None: the search stops, the graph and the map drawn so far stay); the robust
        kernel's width is the graph's from its start."""
        with self._lock:
            self._wait_redraws()  # a rebuild is drawn under one configuration, begun and shown
            self._swap_in()
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
            self._mapper.adopt_front()  # the range noise a new configuration may give
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

    def keyframe_array(self) -> FloatArray:
        """:meth:`keyframe_rows` as one array ``(K, 5)``. O(keyframes), vectorised."""
        with self._lock:
            return self._mapper.keyframe_array()

    def keyframe_changes(self, seen: object | None, since: int) -> tuple[object, int, FloatArray]:
        """What a reader that last read the graph's estimate ``seen`` (this method's first answer) must
        compare to find the keyframes that moved or are new: ``(estimate, first, rows)``, ``rows`` the
        keyframe rows from id ``first`` on (:meth:`keyframe_array`): from ``since`` when the estimate is
        still ``seen`` (the rows before it are as they were then), else all. Read under one lock, so the
        rows are those of the estimate returned. O(rows): the new keyframes between two optimisations,
        not every keyframe each step (the agent's step at a day's 70,000 keyframes)."""
        with self._lock:
            estimate = self._mapper.graph.pose_array()
            first = since if estimate is seen else 0
            return estimate, first, self._mapper.keyframe_array(first)

    def closure_pairs(self, since: int = 0) -> list[list[int]]:
        """The accepted loop closures from the ``since``-th on, ``[keyframe_id_a, keyframe_id_b]``.
        O(closures since)."""
        with self._lock:
            return self._mapper.closure_pairs(since)

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
