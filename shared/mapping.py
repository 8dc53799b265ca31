"""Offline mapping: turn a simulated world or a laser log into a line map (GeoJSON, SVG/PNG, DXF, ROS
occupancy map, trajectory CSV): the work behind ``linemap map``, the benchmarks and the report.

The work is split so it can be tested without a terminal: :func:`open_source` resolves ``INPUT`` into a
stream of scans plus what is known about it (laser offset, ground truth), :func:`map_scans` runs the
pipeline over the stream, and :func:`write_outputs` writes the files.
"""

from __future__ import annotations

import logging
import os
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from shared.errors import LinemapError
from shared.io.errors import NoScansError
from shared.pipeline import MapSnapshot, Pipeline, PipelineConfig
from shared.pipeline.pipeline import StepResult
from shared.sim import World, default_world, load_world, simulate_run
from shared.slam import GraphMapper, LoopClosureSettings
from shared.slam.frontproc import FrontEndProcess
from shared.types import FloatArray, Pose2D, Scan

__all__ = [
    "EXPECTED_SCANS",
    "MapRun",
    "MappingStoppedError",
    "Source",
    "loop_settings",
    "map_scans",
    "no_scans",
    "open_source",
    "write_outputs",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class Source:
    """An opened input: scans to stream, the laser's mounting offset, and ground truth when simulated."""

    name: str
    scans: Iterable[Scan]
    laser_offset: Pose2D
    total: int | None
    world: World | None = None
    true_trajectory: FloatArray | None = None
    closer: AbstractContextManager[Any] | None = None
    #: For a log: its path and format name (what "no scans found" names).
    log_path: Path | None = None
    log_format: str | None = None
    #: For a log: the share of it read so far, in [0, 1] (None when it cannot be told).
    progress: Callable[[], float | None] | None = None


def open_source(
    spec: str,
    *,
    log_format: str | None = None,
    seed: int = 0,
    scan_topic: str | None = None,
    odom_topic: str | None = None,
) -> Source:
    """``sim`` (the default world), ``sim:WORLD_FILE`` (JSON/TOML walls) or a log path (CARMEN, .dat, or a
    ROS bag: ROS 1 ``.bag``, rosbag2 folder, ``.db3`` or ``.mcap``; ``scan_topic`` / ``odom_topic`` choose
    its topics)."""
    if spec == "sim" or spec.startswith("sim:"):
        world = default_world() if spec == "sim" else load_world(Path(spec[4:]))
        run = simulate_run(world, seed=seed)
        return Source(
            f"simulated world '{world.name}'",
            run.scans,
            run.drive.laser_offset,
            len(run.scans),
            world,
            run.trajectory("true"),
        )
    from shared.io import open_log
    from shared.io.errors import LogFormatError, RosbagError

    try:
        reader = open_log(Path(spec), log_format, scan_topic=scan_topic, odom_topic=odom_topic)
    except (LogFormatError, RosbagError) as exc:  # the first record or the container is broken: no scan
        fmt = log_format or _format_of(Path(spec))
        raise no_scans(
            Source(spec, (), Pose2D(0.0, 0.0, 0.0), 0, log_path=Path(spec), log_format=fmt), exc
        ) from None
    return Source(
        f"{reader.info.format} log {Path(spec).name}",
        reader,
        reader.info.laser_offset,
        None,
        closer=reader,
        log_path=Path(spec),
        log_format=reader.info.format,
        progress=reader.progress,
    )


#: What each log reader reads, for the "no scans found" error (format name -> description).
EXPECTED_SCANS = {
    "carmen": "a CARMEN log (.clf/.log) with FLASER, RLASER, ROBOTLASER1 or ROBOTLASER2 laser records",
    "breezyslam": "a BreezySLAM log (.dat) with one line of 707 integers per scan (time, encoders, ranges)",
    "rosbag": "a ROS bag (.bag, .db3, .mcap or a rosbag2 folder) with sensor_msgs/LaserScan messages",
}


def _format_of(path: Path) -> str | None:
    from shared.io import detect_format

    try:
        return detect_format(path)
    except LinemapError:
        return None


def no_scans(source: Source, cause: LinemapError | None = None) -> NoScansError:
    """The error for a log ``source`` that gave no scan: names the file and what its reader expects."""
    expected = EXPECTED_SCANS.get(source.log_format or "", f"a {source.log_format} log with laser scans")
    why = f" (the first record failed: {cause})" if cause is not None else ""
    return NoScansError(f"no scans found in {source.log_path}: expected {expected}{why}")


@dataclass(frozen=True, slots=True)
class MapRun:
    """What a mapping run produced and how fast."""

    snapshot: MapSnapshot
    scans: int
    seconds: float
    icp_used: int
    step_median_ms: float
    step_p99_ms: float
    #: loop closures accepted (0 without the pose graph)
    loop_closures: int = 0

    @property
    def scans_per_s(self) -> float:
        """Throughput, reading and flushing included, from the second scan on (the first compiles)."""
        return (self.scans - 1) / self.seconds if self.seconds > 0 and self.scans > 1 else 0.0


def map_scans(
    source: Source,
    config: PipelineConfig,
    *,
    limit: int | None = None,
    on_step: Callable[[int], None] | None = None,
    loop_closure: LoopClosureSettings | None = None,
    front_process: bool | None = None,
) -> MapRun:
    """Run the pipeline over every scan of ``source`` (at most ``limit``), then flush pending batches.

    With ``loop_closure`` the pipeline runs under a keyframe pose graph (:class:`shared.slam.GraphMapper`):
    loops are closed as they are found and the map is drawn again from the corrected poses at the end.
    The front end then tracks in a child process ahead of the graph (:mod:`shared.slam.frontproc`; the
    same map bit for bit) where the machine has more than one core, or where ``front_process`` says so.

    A malformed record part-way through a log stops the run but loses nothing: :class:`MappingStoppedError`
    carries the map of the scans read before it.
    """
    if front_process is None:
        front_process = (os.cpu_count() or 1) > 1
    if loop_closure is not None and loop_closure.enabled and front_process:
        return _map_beside_front(source, config, loop_closure, limit=limit, on_step=on_step)
    pipeline: Pipeline | GraphMapper
    if loop_closure is None:
        pipeline = Pipeline(config, laser_offset=source.laser_offset)
    else:
        # searching for loops, the front end tracks poses only: the map is drawn once, at the end, from
        # the corrected poses (loop closure off: the front end's own map, as without the graph)
        front = Pipeline(config, laser_offset=source.laser_offset, track_only=loop_closure.enabled)
        pipeline = GraphMapper(
            lambda: Pipeline(config, laser_offset=source.laser_offset), loop_closure, front=front
        )
    tally = _Tally(on_step)
    failure: LinemapError | None = None
    with source.closer or nullcontext():
        scans: Iterator[Scan] = iter(source.scans)
        while limit is None or tally.count < limit:
            try:
                scan = next(scans)
            except StopIteration:
                break
            except LinemapError as exc:  # a broken record: keep what was mapped so far
                failure = exc
                break
            tally.add(pipeline.step(scan))
    tally.check(source, limit, failure)
    if isinstance(pipeline, GraphMapper):
        snapshot = pipeline.finish()
        timing = pipeline.front.timing_ms()
    else:
        pipeline.flush()
        snapshot = pipeline.snapshot()
        timing = pipeline.timing_ms()
    closures = len(pipeline.closures) if isinstance(pipeline, GraphMapper) else 0
    return tally.run(snapshot, timing, closures, failure)


@dataclass(slots=True)
class _Tally:
    """A run's scans stepped and ICP corrections, and its clock (from the second scan on: the first
    compiles the kernels, once per machine, which is not throughput)."""

    on_step: Callable[[int], None] | None
    count: int = 0
    icp: int = 0
    start: float = field(default_factory=time.perf_counter)

    def add(self, result: StepResult) -> None:
        self.count += 1
        self.icp += result.icp_used
        if self.count == 1:
            self.start = time.perf_counter()
        if self.on_step is not None:
            self.on_step(self.count)

    def check(self, source: Source, limit: int | None, failure: LinemapError | None) -> None:
        """:class:`NoScansError` when a log gave no scans: an empty map from an empty or foreign file is
        not a result."""
        if self.count == 0 and source.log_path is not None and (limit is None or limit > 0):
            raise no_scans(source, failure)

    def run(
        self,
        snapshot: MapSnapshot,
        timing_ms: tuple[float, float],
        closures: int,
        failure: LinemapError | None,
    ) -> MapRun:
        """The :class:`MapRun`, or :class:`MappingStoppedError` carrying it after a broken record."""
        seconds = time.perf_counter() - self.start
        run = MapRun(snapshot, self.count, seconds, self.icp, *timing_ms, closures)
        if failure is not None:
            raise MappingStoppedError(failure, run)
        return run


#: scans the front end's process may be ahead of the graph (what waits in the pipes)
AHEAD_SCANS = 256


def _map_beside_front(
    source: Source,
    config: PipelineConfig,
    loop_closure: LoopClosureSettings,
    *,
    limit: int | None,
    on_step: Callable[[int], None] | None,
) -> MapRun:
    """:func:`map_scans` with loop closure, the front end tracking in a child process at most
    :data:`AHEAD_SCANS` scans ahead of the graph here (:mod:`shared.slam.frontproc`)."""
    front = Pipeline(config, laser_offset=source.laser_offset, track_only=True)  # never stepped here
    mapper = GraphMapper(
        lambda: Pipeline(config, laser_offset=source.laser_offset), loop_closure, front=front
    )
    tally = _Tally(on_step)
    read = 0
    failure: LinemapError | None = None
    pending: deque[Scan] = deque()
    with source.closer or nullcontext(), FrontEndProcess(config, source.laser_offset) as child:
        scans: Iterator[Scan] = iter(source.scans)

        def read_ahead() -> None:
            """Send scans until AHEAD_SCANS wait, the input ends (or breaks) or ``limit`` is read."""
            nonlocal read, failure
            while len(pending) < AHEAD_SCANS and not child.input_closed:
                if limit is not None and read >= limit:
                    child.close_input()
                    return
                try:
                    scan = next(scans)
                except StopIteration:
                    child.close_input()
                    return
                except LinemapError as exc:  # a broken record: keep what was mapped so far
                    failure = exc
                    child.close_input()
                    return
                read += 1
                pending.append(scan)
                child.send(scan)

        read_ahead()
        for tracked in child.results():
            tally.add(mapper.step(pending.popleft(), tracked=tracked))
            read_ahead()
    tally.check(source, limit, failure)
    return tally.run(mapper.finish(), child.timing_ms, len(mapper.closures), failure)


def loop_settings(
    enabled: bool, search_radius_m: float | None = None, min_inlier_share: float | None = None
) -> LoopClosureSettings | None:
    """The command line's loop-closure choices as settings (``None`` when off); a bad value raises
    :class:`shared.slam.LoopClosureSettingsError` naming it."""
    if not enabled:
        return None
    given = {"search_radius_m": search_radius_m, "min_inlier_share": min_inlier_share}
    return LoopClosureSettings.parse({k: v for k, v in given.items() if v is not None})


class MappingStoppedError(LinemapError):
    """The input broke part-way; ``run`` holds the map of the scans read before the bad record."""

    def __init__(self, cause: LinemapError, run: MapRun) -> None:
        super().__init__(f"{cause} (stopped after {run.scans} good scans; their map is kept)")
        self.cause = cause
        self.run = run


def write_outputs(
    snapshot: MapSnapshot,
    *,
    geojson: Path | None,
    svg: Path | None = None,
    png: Path | None = None,
    trajectory: Path | None = None,
    walls: FloatArray | None = None,
    title: str | None = None,
    dxf: Path | None = None,
    occupancy: Path | None = None,
    resolution_m: float = 0.05,
    mcap: Path | None = None,
) -> list[Path]:
    """Write the requested files; returns the paths written (``occupancy`` gives two: the PGM image and
    its map_server YAML, see :func:`shared.export.occupancy_paths`; ``resolution_m`` is its metres per
    pixel)."""
    from shared.export import render_map, write_dxf, write_geojson, write_occupancy, write_trajectory_csv

    written: list[Path] = []
    if geojson is not None:
        write_geojson(geojson, snapshot)
        written.append(geojson)
    if trajectory is not None:
        write_trajectory_csv(trajectory, snapshot.trajectory)
        written.append(trajectory)
    for picture in (svg, png):
        if picture is not None:
            render_map(snapshot, picture, walls=walls, title=title)
            written.append(picture)
    if dxf is not None:
        write_dxf(dxf, snapshot)
        written.append(dxf)
    if occupancy is not None:
        written.extend(write_occupancy(occupancy, snapshot, resolution_m=resolution_m))
    if mcap is not None:
        from shared.export import write_map_mcap

        written.append(write_map_mcap(mcap, snapshot))
    return written
