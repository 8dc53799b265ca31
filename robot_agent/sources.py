"""Where the agent's scans come from: ``sim``, ``sim:WORLD_FILE``, ``sim:KIND``, a log file, or
``urg:DEVICE``.

Sources are plain iterators of :class:`shared.types.Scan` (with odometry); pacing is the agent's job. A
source that cannot be opened raises :class:`SourceError` naming the spec and what was expected.

A simulated robot drives its world's path once, or patrols it ``laps`` times (0: until stopped; see
:func:`shared.sim.patrol_scans`). ``sim:KIND`` is a world of the scenario suite
(:data:`shared.sim.worlds.KINDS`, e.g. ``sim:corridor-doors``; world files end in .json/.toml, so a kind
never names one): once, its case as ``linemap bench worlds`` maps it; in laps, patrolled out and back with
its people, doors and odometry errors (:func:`shared.sim.scene_patrol_scans`).

``urg:DEVICE`` streams a Hokuyo URG-04LX on the serial device (SCIP 2.0, :mod:`robot_agent.sensors.urg`):
scans stamped in host seconds, recovering from damaged frames and replugs. Its scans carry no odometry
unless ``encoders`` names the serial device of the wheel-encoder bridge
(:mod:`robot_agent.sensors.encoders`): each scan then gets the wheel-odometry pose interpolated at its
time stamp (:func:`robot_agent.sensors.pairing.paired_scans`; a scan with no reading within 0.1 s keeps
``odometry=None`` and the pipeline predicts no motion for it).

:func:`is_live` tells a sensor (which cannot be replayed) from a simulated run or a log (which can).
"""

from __future__ import annotations

import threading
from collections.abc import Generator, Iterator
from pathlib import Path

from robot_agent.errors import SourceError
from shared.errors import LinemapError
from shared.types import Pose2D, Scan

__all__ = ["default_rate_hz", "is_live", "laser_offset", "open_scans"]


def is_live(spec: str) -> bool:
    """Whether ``spec`` is a live sensor (``urg:``): a restarted agent cannot skip what it already mapped."""
    return spec.startswith("urg:")


def default_rate_hz(spec: str) -> float:
    """The pace a source runs at unless told otherwise: the URG-04LX's 10 Hz."""
    return 10.0


def laser_offset(spec: str) -> Pose2D:
    """The scanner's pose in the robot frame for the scans of ``spec`` (m, rad): the simulated robot's
    (:data:`shared.odometry.MINES_ROVER`, which :func:`shared.sim.simulate_run` drives), a log's own (its
    header, as ``linemap map`` reads it), identity for a live sensor (the robot's configuration gives it).

    The pipeline needs it: odometry is the robot's motion, the scan the scanner's; with the scanner 0.145 m
    ahead of the axle and no offset, every turn in place moves the scanner along an arc the pose does not
    follow, and the walls seen on the way out and on the way back land 10-30 cm apart (docs/worlds.md)."""
    if spec == "sim" or spec.startswith("sim:"):
        from shared.odometry import MINES_ROVER

        return MINES_ROVER.laser_offset
    if is_live(spec) or not Path(spec).exists():
        return Pose2D()
    from shared.io import open_log

    try:
        with open_log(Path(spec), None) as reader:
            return reader.info.laser_offset
    except LinemapError as exc:
        raise SourceError(f"source {spec!r}: {exc}") from None


def open_scans(
    spec: str,
    *,
    seed: int = 0,
    laps: int = 1,
    encoders: str | None = None,
    stop: threading.Event | None = None,
    reconnect_for_s: float | None = 60.0,
) -> Generator[Scan, None, None]:
    """Scans from ``spec`` (see the module docstring); closing the generator releases the device.

    ``encoders``, ``stop`` and ``reconnect_for_s`` apply to ``urg:DEVICE``: the wheel-encoder bridge's
    serial device, an event that ends the stream (also while waiting for a replugged device), and how long
    to keep trying to reopen a vanished device before giving up (None: until ``stop``).
    """
    if laps != 1 and not (spec == "sim" or spec.startswith("sim:")):
        raise SourceError(
            f"source {spec!r}: laps = {laps} applies to simulated sources ('sim', 'sim:WORLD') only"
        )
    if spec.startswith("urg:"):
        if encoders is None:
            yield from _urg_scans(spec, stop, reconnect_for_s)
        else:
            yield from _paired(spec, encoders, stop, reconnect_for_s)
        return
    if encoders is not None:
        raise SourceError(
            f"source {spec!r}: encoders = {encoders!r} applies to 'urg:DEVICE' only (the others carry "
            "their own odometry)"
        )
    if spec == "sim" or spec.startswith("sim:"):
        from shared.sim import default_world, load_world, patrol_scans, scene_patrol_scans, simulate_run
        from shared.sim.worlds import KINDS, simulate_case

        if spec[4:] in KINDS:
            if laps == 1:
                yield from simulate_case(spec[4:], seed).run.scans
            else:
                yield from scene_patrol_scans(spec[4:], seed=seed, laps=laps)
            return
        if spec != "sim" and not Path(spec[4:]).suffix:
            raise SourceError(
                f"source {spec!r}: {spec[4:]!r} is neither a world file (.json/.toml) nor a world kind of "
                f"the scenario suite ({', '.join(KINDS)})"
            )
        try:
            world = default_world() if spec == "sim" else load_world(Path(spec[4:]))
        except LinemapError as exc:
            raise SourceError(f"source {spec!r}: {exc}") from None
        if laps == 1:
            yield from simulate_run(world, seed=seed).scans
        else:
            try:
                yield from patrol_scans(world, seed=seed, laps=laps)
            except LinemapError as exc:
                raise SourceError(f"source {spec!r}: {exc}") from None
        return
    from shared.io import open_log

    path = Path(spec)
    if not path.exists():  # a file, or a rosbag2 folder
        raise SourceError(
            f"source {spec!r}: no such file (expected 'sim', 'sim:WORLD_FILE', a log, a ROS bag or "
            "'urg:DEVICE')"
        )
    try:
        with open_log(path, None) as reader:
            yield from reader
    except LinemapError as exc:
        raise SourceError(f"source {spec!r}: {exc}") from None


def _paired(
    spec: str, encoders: str, stop: threading.Event | None, reconnect_for_s: float | None
) -> Iterator[Scan]:
    """The laser's scans with the wheel encoders' odometry at their time stamps (one host clock)."""
    from robot_agent.sensors.encoders import EncoderError, SerialOdometry
    from robot_agent.sensors.pairing import paired_scans

    if not encoders:
        raise SourceError(f"source {spec!r}: encoders = '': expected the bridge's serial device")
    try:
        wheels = SerialOdometry(encoders).open()
    except EncoderError as exc:
        raise SourceError(f"source {spec!r}: the wheel encoders could not start: {exc}") from None
    try:
        yield from paired_scans(_urg_scans(spec, stop, reconnect_for_s), wheels, on_gap="flag")
    except EncoderError as exc:
        raise SourceError(f"source {spec!r}: wheel encoders: {exc}") from None
    finally:
        wheels.close()


def _urg_scans(spec: str, stop: threading.Event | None, reconnect_for_s: float | None) -> Iterator[Scan]:
    from robot_agent.sensors.errors import SensorError
    from robot_agent.sensors.urg import UrgDriver

    device = spec[4:]
    if not device:
        raise SourceError(f"source {spec!r}: expected 'urg:DEVICE', e.g. 'urg:/dev/ttyACM0'")
    try:
        driver = UrgDriver(device, give_up_after_s=reconnect_for_s, stop=stop)
        driver.open()
    except SensorError as exc:
        raise SourceError(f"source {spec!r}: the URG-04LX serial driver could not start: {exc}") from None
    try:
        with driver:
            yield from driver.scans()
    except SensorError as exc:
        raise SourceError(f"source {spec!r}: {exc}") from None
