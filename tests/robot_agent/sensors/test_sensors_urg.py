"""The URG-04LX driver against the emulated sensor through a real pseudo-terminal: VV/PP/II, GD and MD
scans equal to the emulated ones to the mm, clusters, error codes, the SCIP 1.1 boot, the timer's wrap."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
import serial  # type: ignore[import-untyped]

from robot_agent.sensors.emulator import UrgEmulator
from robot_agent.sensors.errors import SensorDisconnectedError
from robot_agent.sensors.scip import TIMESTAMP_MODULUS
from robot_agent.sensors.scip_info import URG04LX_PARAMS
from robot_agent.sensors.urg import UrgDriver
from shared.sim import SimRun
from shared.types import URG04LX, Scan
from tests.robot_agent.sensors.urgtools import SAFETY_S, ScanIndex, mm


def test_info_commands(sim_run: SimRun, tmp_path: Path) -> None:
    with UrgEmulator(sim_run.scans, link=tmp_path / "ttyURG") as emu, UrgDriver(emu.path) as urg:
        assert (
            Path(emu.path).is_symlink() and emu.tty_name is not None and emu.tty_name.startswith("/dev/pts/")
        )
        assert urg.parameters() == URG04LX_PARAMS
        v = urg.versions()
        assert v.product == "SOKUIKI Sensor URG-04LX" and v.protocol == "SCIP 2.0"
        assert not urg.state().laser_on
        urg.laser_on()
        state = urg.state()
        assert state.laser_on and state.model == URG04LX_PARAMS.model
        urg.laser_off()
        assert not urg.state().laser_on
        assert not urg.switched_from_scip1
    assert not Path(emu.path).exists()  # the emulator removes its device link


def test_single_scans_equal_the_emulated_ones_to_the_mm(sim_run: SimRun, tmp_path: Path) -> None:
    with UrgEmulator(sim_run.scans, link=tmp_path / "ttyURG") as emu, UrgDriver(emu.path) as urg:
        got = [urg.scan() for _ in range(5)]
    for scan, want in zip(got, sim_run.scans, strict=False):
        assert scan.beam_count == URG04LX.beam_count == 682
        assert scan.angle_min_rad == URG04LX.angle_min_rad
        assert scan.angle_increment_rad == URG04LX.angle_increment_rad
        assert (scan.range_min_m, scan.range_max_m) == (0.02, 5.6)
        assert scan.odometry is None
        np.testing.assert_array_equal(mm(scan), mm(want))
        assert np.array_equal(np.isnan(scan.ranges_m), ~np.isfinite(want.ranges_m))
        finite = np.isfinite(want.ranges_m)
        assert np.max(np.abs(scan.ranges_m[finite] - want.ranges_m[finite])) <= 0.0005 + 1e-12


def test_a_continuous_stream_delivers_every_scan_in_order(sim_run: SimRun, tmp_path: Path) -> None:
    n = 40
    index = ScanIndex(sim_run.scans)
    with UrgEmulator(sim_run.scans, link=tmp_path / "ttyURG") as emu, UrgDriver(emu.path) as urg:
        got = list(itertools.islice(urg.scans(), n))
        assert urg.stats.dropped_frames == 0 and urg.stats.reconnects == 0
        assert emu.commands[-1] == b"QT"  # closing the stream stops the sensor
    assert [index(s) for s in got] == list(range(n))
    stamps = [s.stamp_s for s in got]
    assert all(b > a for a, b in itertools.pairwise(stamps))


def test_a_stream_of_n_scans_ends_by_itself(sim_run: SimRun, tmp_path: Path) -> None:
    index = ScanIndex(sim_run.scans)
    with UrgEmulator(sim_run.scans, link=tmp_path / "ttyURG") as emu, UrgDriver(emu.path) as urg:
        got = list(urg.scans(count=7, interval=1))  # every other scan
        assert emu.commands[-2:] == [b"MD0044072501107", b"QT"]
        assert urg.scan() is not None  # the driver is still usable
    assert [index(s) for s in got] == [0, 2, 4, 6, 8, 10, 12]


def test_clusters_report_their_nearest_step(sim_run: SimRun, tmp_path: Path) -> None:
    with UrgEmulator(sim_run.scans, link=tmp_path / "ttyURG") as emu, UrgDriver(emu.path) as urg:
        scan = next(urg.scans(start_step=100, end_step=699, cluster=3))
    want = mm(sim_run.scans[0])[100 - 44 : 700 - 44].reshape(-1, 3)
    nearest = np.where(want > 0, want, np.iinfo(np.int64).max).min(axis=1)
    expected = np.where((want > 0).any(axis=1), nearest, -1)
    np.testing.assert_array_equal(mm(scan), expected)
    step = URG04LX.angle_increment_rad
    assert scan.angle_increment_rad == pytest.approx(3 * step)
    assert scan.angle_min_rad == pytest.approx((101 - 384) * step)  # the middle step of the first cluster


def test_error_codes_below_20_mm_are_no_returns(tmp_path: Path) -> None:
    ranges = np.full(682, 2.0)
    ranges[10:20] = np.nan  # no return: sent as an error code (7 here)
    ranges[30:35] = 9.0  # beyond DMAX
    ranges[40] = 0.005  # closer than DMIN
    scan = Scan.from_geometry(URG04LX, ranges)
    with UrgEmulator([scan], link=tmp_path / "ttyURG", no_return_code=7) as emu, UrgDriver(emu.path) as urg:
        got = urg.scan()
    assert np.isnan(got.ranges_m[10:20]).all() and np.isnan(got.ranges_m[30:35]).all()
    assert np.isnan(got.ranges_m[40])
    assert np.count_nonzero(np.isnan(got.ranges_m)) == 16
    assert np.all(got.ranges_m[~np.isnan(got.ranges_m)] == 2.0)


def test_a_sensor_booting_in_scip_1_1_is_switched(sim_run: SimRun, tmp_path: Path) -> None:
    link = tmp_path / "ttyURG"
    with UrgEmulator(sim_run.scans, link=link, scip1_boot=True) as emu:
        # In SCIP 1.1 the sensor refuses SCIP 2.0 commands (seen on the raw port) ...
        with serial.Serial(emu.path, 115200, timeout=SAFETY_S) as raw:
            raw.write(b"VV\n")
            assert raw.read_until(b"\n\n") == b"VV\nE\n\n"
        # ... and the driver switches it first.
        with UrgDriver(emu.path) as urg:
            assert urg.switched_from_scip1
            assert urg.versions().protocol == "SCIP 2.0"
            assert next(urg.scans()).beam_count == 682
        assert emu.commands[:3] == [b"VV", b"SCIP2.0", b"QT"]


def test_the_24_bit_timer_wraps_without_a_jump(sim_run: SimRun, tmp_path: Path) -> None:
    """A host clock that ticks 0.1 s per scan, a sensor timer 300 ms before its wrap: the mapped stamps
    step by 0.1 s straight through the wrap."""
    ticks = itertools.count()
    start = TIMESTAMP_MODULUS - 300
    with (
        UrgEmulator(sim_run.scans, link=tmp_path / "ttyURG", start_time_ms=start) as emu,
        UrgDriver(emu.path, clock=lambda: 5000.0 + 0.1 * next(ticks)) as urg,
    ):
        got = list(itertools.islice(urg.scans(), 8))
        raw = [f.timestamp_ms for f in emu.frames[:8]]
    assert raw[0] > raw[-1]  # the sensor's timer wrapped
    steps = np.diff([s.stamp_s for s in got])
    np.testing.assert_allclose(steps, 0.1, atol=1e-6)


def test_a_missing_device_fails_at_once_naming_it(tmp_path: Path) -> None:
    missing = tmp_path / "ttyNothing"
    with pytest.raises(SensorDisconnectedError, match=r"cannot open serial port .*ttyNothing"):
        UrgDriver(str(missing)).open()


def test_a_device_that_stays_away_ends_the_stream_with_a_clear_error(sim_run: SimRun, tmp_path: Path) -> None:
    with UrgEmulator(sim_run.scans, link=tmp_path / "ttyURG") as emu:
        urg = UrgDriver(emu.path, give_up_after_s=0.3)
        with urg:
            stream = urg.scans()
            next(stream)
            emu.unplug()  # no replug
            with pytest.raises(SensorDisconnectedError, match="not back after"):
                for _ in stream:
                    pass
        assert urg.stats.open_failures >= 1


def test_stop_ends_the_stream(sim_run: SimRun, tmp_path: Path) -> None:
    with UrgEmulator(sim_run.scans, link=tmp_path / "ttyURG") as emu, UrgDriver(emu.path) as urg:
        got = []
        for scan in urg.scans():
            got.append(scan)
            if len(got) == 3:
                urg.stop.set()
        assert len(got) == 3


def test_a_paced_sensor_streams_in_order(sim_run: SimRun, tmp_path: Path) -> None:
    """At a rate of its own the emulator skips a scan the reader has not taken in time (as a sensor
    does), so only the order is certain."""
    index = ScanIndex(sim_run.scans)
    with (
        UrgEmulator(sim_run.scans, link=tmp_path / "ttyURG", rate_hz=50.0) as emu,
        UrgDriver(emu.path) as urg,
    ):
        got = [index(s) for s in itertools.islice(urg.scans(), 10)]
    assert got == sorted(set(got)) and len(got) == 10
    assert got == [f.scan_index for f in emu.frames[: len(got)]]
