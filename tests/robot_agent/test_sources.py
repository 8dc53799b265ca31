"""The agent's scan sources: the simulated robot's patrol is one continuous drive (time and odometry); a
URG-04LX (emulated on a pty) streams through ``urg:DEVICE``."""

from __future__ import annotations

import itertools
import math
import os
import threading
from pathlib import Path

import pytest

from robot_agent.errors import SourceError
from robot_agent.sensors.emulator import UrgEmulator
from robot_agent.sensors.encoder_emulator import BridgeEmulator, SimOdometry, open_pty
from robot_agent.sources import laser_offset, open_scans
from shared.io.carmen_write import write_carmen
from shared.sim import default_world, simulate_run
from shared.types import Pose2D


def test_one_lap_is_the_plain_simulated_run() -> None:
    ours = [s.stamp_s for s in open_scans("sim", seed=3)]
    assert ours == [s.stamp_s for s in simulate_run(default_world(), seed=3).scans]


def test_patrol_runs_on_with_continuous_time_and_odometry() -> None:
    one_lap = len(simulate_run(default_world(), seed=0).scans)
    scans = list(itertools.islice(open_scans("sim", laps=0), 4 * one_lap))
    assert len(scans) == 4 * one_lap  # 0 laps: until stopped
    stamps = [s.stamp_s for s in scans]
    steps = [b - a for a, b in itertools.pairwise(stamps)]
    assert min(steps) == pytest.approx(0.1) and max(steps) == pytest.approx(0.1)
    odo = [s.odometry for s in scans]
    assert all(o is not None for o in odo)
    for a, b in itertools.pairwise(odo):
        assert a is not None and b is not None
        # at 0.4 m/s and 0.8 rad/s, 10 Hz: no jump between laps
        assert math.hypot(b.x_m - a.x_m, b.y_m - a.y_m) < 0.08
        assert abs(math.remainder(b.theta_rad - a.theta_rad, math.tau)) < 0.15


def test_the_scanner_offset_is_the_sources_own(tmp_path: Path) -> None:
    run = simulate_run(default_world(), seed=0)
    assert laser_offset("sim") == run.drive.laser_offset != Pose2D()  # the simulated robot's, 0.145 m ahead
    log = tmp_path / "run.clf"
    write_carmen(log, run.scans[:3], laser_offset=Pose2D(0.2, 0.0, 0.0))
    assert laser_offset(str(log)).x_m == pytest.approx(0.2)  # a log's header
    assert laser_offset("urg:/dev/none") == Pose2D()  # a live sensor: the robot's configuration says


def test_laps_count_is_kept() -> None:
    one_lap = len(simulate_run(default_world(), seed=0).scans)
    n = sum(1 for _ in open_scans("sim", laps=2))
    assert 3 * one_lap < n < 5 * one_lap  # a lap is out along the path and back


def test_laps_on_a_log_is_refused(tmp_path: pytest.TempPathFactory) -> None:
    with pytest.raises(SourceError, match="simulated sources"):
        next(open_scans("some.log", laps=3))


def test_urg_without_a_device_is_refused() -> None:
    with pytest.raises(SourceError, match=r"'urg:': expected 'urg:DEVICE'"):
        next(open_scans("urg:"))


def test_urg_on_a_missing_device_names_it(tmp_path: Path) -> None:
    spec = f"urg:{tmp_path / 'ttyACM9'}"
    with pytest.raises(SourceError, match=r"URG-04LX serial driver could not start: .*ttyACM9"):
        next(open_scans(spec))


def test_urg_refuses_laps_and_others_refuse_encoders() -> None:
    with pytest.raises(SourceError, match="simulated sources"):
        next(open_scans("urg:/dev/ttyACM0", laps=2))
    with pytest.raises(SourceError, match="applies to 'urg:DEVICE' only"):
        next(open_scans("sim", encoders="/dev/ttyUSB0"))


def test_urg_with_a_missing_encoder_bridge_names_it(tmp_path: Path) -> None:
    scans = simulate_run(default_world(), seed=0).scans
    with UrgEmulator(scans, link=tmp_path / "ttyURG") as emu:
        source = open_scans("urg:" + emu.path, encoders=str(tmp_path / "ttyUSB7"))
        with pytest.raises(SourceError, match=r"wheel encoders could not start: .*ttyUSB7"):
            next(source)


def test_urg_scans_take_the_wheel_odometry_and_end_on_stop(tmp_path: Path) -> None:
    """A laser and an encoder bridge, each emulated on its own pty: the scans come with the bridge's
    odometry (interpolated at their host time stamps, both on the host clock); stop ends both."""
    run = simulate_run(default_world(), seed=0)
    sim = SimOdometry(run, substeps=5)
    master, slave, bridge_path = open_pty()
    stop = threading.Event()
    try:
        with (
            UrgEmulator(run.scans, link=tmp_path / "ttyURG") as emu,
            BridgeEmulator(master, sim.lines(), info=sim.info, pace_s=0.01) as bridge,
        ):
            plain = list(itertools.islice(open_scans("urg:" + emu.path), 3))
            assert [s.odometry for s in plain] == [None, None, None]
            got = []
            for scan in open_scans("urg:" + emu.path, encoders=bridge_path, stop=stop):
                got.append(scan)
                if len(got) == 20:
                    stop.set()  # the stream ends at the next frame
            assert bridge.error is None and bridge.hellos >= 1
    finally:
        os.close(slave)
    assert len(got) == 20
    with_odometry = [s.odometry for s in got if s.odometry is not None]
    assert with_odometry, "the scans are paired with the wheel odometry"
    start = run.odometry_poses[0]  # the bridge's odometry starts at the origin of its own frame
    rel = [start.between(p) for p in run.odometry_poses]
    xs, ys = [p.x_m for p in rel], [p.y_m for p in rel]
    for pose in with_odometry:  # poses the bridge's run passes through, not made up
        assert min(xs) - 0.01 <= pose.x_m <= max(xs) + 0.01 and min(ys) - 0.01 <= pose.y_m <= max(ys) + 0.01


def test_a_rosbag2_folder_replays_like_its_scans(tmp_path: Path) -> None:
    from tests.shared.io.test_io_rosbag import Bag, odometry_at_scans, write_bag

    scans = simulate_run(default_world(), seed=0).scans[:30]
    bag = write_bag(tmp_path / "run", "sqlite3", Bag({"/scan": scans}, odometry=odometry_at_scans(scans)))
    assert bag.is_dir()
    got = list(open_scans(str(bag)))
    assert [s.stamp_s for s in got] == pytest.approx([s.stamp_s for s in scans], abs=1e-9)
    assert all(g.odometry is not None for g in got)


def test_a_suite_world_is_a_simulated_source() -> None:
    """``sim:KIND``: once, the suite's case as ``linemap bench worlds`` maps it; in laps, its patrol; the
    simulated robot's scanner offset; an unknown name lists the kinds."""
    from shared.sim.worlds import simulate_case

    once = [s.stamp_s for s in open_scans("sim:glass-black", seed=2)]
    assert once == [s.stamp_s for s in simulate_case("glass-black", 2).run.scans]
    patrol = list(itertools.islice(open_scans("sim:people-across", laps=0), 30))
    assert len(patrol) == 30 and all(s.odometry is not None for s in patrol)
    assert laser_offset("sim:people-across") == laser_offset("sim")
    with pytest.raises(SourceError, match="corridor-doors"):
        next(open_scans("sim:corridor-door", laps=0))
