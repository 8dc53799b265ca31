"""The serial encoder source through a real pseudo-terminal, against an emulated bridge that sends the
lines of a simulated run: same counts and poses as the simulator to the tick, bad lines skipped and
counted, counter and clock wrap, geometry from the bridge or from configuration, and the failures."""

from __future__ import annotations

import itertools
import logging
import math
import os
from collections.abc import Iterator

import pytest

from robot_agent.sensors.encoder_emulator import BridgeEmulator, SimOdometry, open_pty
from robot_agent.sensors.encoders import (
    EncoderDecoder,
    EncoderError,
    OdometryReading,
    OdometrySource,
    SerialOdometry,
    checksum,
    format_line,
)
from shared.odometry import DiffDrive
from shared.sim import SimRun, default_world, simulate_run
from shared.types import Pose2D

U32 = 2**32


@pytest.fixture(scope="module")
def run() -> SimRun:
    return simulate_run(default_world(), seed=1)


class Pty:
    """A raw pseudo-terminal: the bridge's side (``master``) and the host's device ``path``."""

    def __init__(self) -> None:
        self.master, self._slave, self.path = open_pty()
        self._open = [self.master, self._slave]

    def hang_up(self) -> None:
        """Close the bridge's side, as when the USB cable is pulled."""
        os.close(self.master)
        self._open.remove(self.master)

    def close(self) -> None:
        for fd in self._open:
            os.close(fd)


@pytest.fixture
def pty() -> Iterator[Pty]:
    terminal = Pty()
    yield terminal
    terminal.close()


def assert_same_poses(got: list[Pose2D], expected: list[Pose2D], drive: DiffDrive) -> None:
    """Equal to the encoders' resolution: one tick of wheel travel, one tick's turn."""
    assert len(got) == len(expected)
    tick_m = drive.metres_per_tick
    for g, e in zip(got, expected, strict=True):
        assert math.hypot(g.x_m - e.x_m, g.y_m - e.y_m) <= tick_m
        assert abs(math.remainder(g.theta_rad - e.theta_rad, math.tau)) <= tick_m / drive.tread_m


@pytest.mark.parametrize("substeps", [1, 5])
def test_serial_source_gives_the_simulators_odometry(run: SimRun, pty: Pty, substeps: int) -> None:
    master, path = pty.master, pty.path
    # the bridge's clock and counters start just below their 32-bit wrap
    sim = SimOdometry(
        run, substeps=substeps, device_epoch_ms=U32 - 2500, tick_origin=(2**31 - 3000, 2**31 - 1000)
    )
    records = [rec for _, rec in sim.records()]
    assert any(b.device_ms < a.device_ms for a, b in itertools.pairwise(records))
    assert any(abs(b.left_ticks - a.left_ticks) > 2**31 for a, b in itertools.pairwise(records))
    assert any(abs(b.right_ticks - a.right_ticks) > 2**31 for a, b in itertools.pairwise(records))
    expected = list(sim)
    assert isinstance(sim, OdometrySource)
    with (
        BridgeEmulator(master, sim.lines(), info=sim.info, wait_for_hello=True) as emulator,
        SerialOdometry(path, origin=run.odometry_poses[0]) as source,
    ):
        assert isinstance(source, OdometrySource)
        got = list(itertools.islice(source, len(expected)))
        drive = source.drive
        stats = source.stats
    assert emulator.error is None and emulator.hellos >= 1
    assert (drive.wheel_diameter_m, drive.tread_m, drive.ticks_per_turn) == pytest.approx((0.154, 0.33, 2000))
    assert stats.info == sim.info and stats.malformed == 0 and stats.readings == len(expected)
    assert [(g.device_ms, g.left_ticks, g.right_ticks) for g in got] == [
        (e.device_ms, e.left_ticks, e.right_ticks) for e in expected
    ]
    assert [(g.left_ticks, g.right_ticks) for g in got[::substeps]] == [tuple(t) for t in run.ticks.tolist()]
    assert_same_poses([g.pose for g in got], [e.pose for e in expected], run.drive)
    assert_same_poses([g.pose for g in got[::substeps]], list(run.odometry_poses), run.drive)
    assert all(b.stamp_s > a.stamp_s for a, b in itertools.pairwise(got))


def test_garbled_lines_are_skipped_and_counted(run: SimRun, pty: Pty) -> None:
    master, path = pty.master, pty.path
    sim = SimOdometry(run, substeps=2)
    clean = sim.lines()
    flipped = bytearray(clean[40])
    flipped[2] = ord("9") if flipped[2] != ord("9") else ord("8")  # a digit of t_ms hit by noise
    garbage = {
        10: [b"E 1 2\n"],  # the bridge sends checksums: a line without one is refused
        20: [b"\x00\xff\xfe garbage\n"],
        30: [b"E 123 4 5*00\n"],
        40: [bytes(flipped)],
        50: [b"Z hello*" + b"%02X" % checksum(b"Z hello") + b"\n"],
        60: [b"9" * 300 + b"\n"],
        70: [clean[70][:7] + b"\n"],  # a line cut short: lost its checksum
        80: [clean[79]],  # the previous line again: its time did not advance
        90: [b"# bridge diagnostics: battery 12.3 V\n", b"\r\n"],  # not errors
    }
    lines = [junk for i, line in enumerate(clean) for junk in [*garbage.get(i, []), line]]
    expected = list(sim)
    with (
        BridgeEmulator(master, lines, info=sim.info, wait_for_hello=True),
        SerialOdometry(path, origin=run.odometry_poses[0]) as source,
    ):
        got = list(itertools.islice(source, len(expected)))
        stats = source.stats
    assert [(g.left_ticks, g.right_ticks) for g in got] == [(e.left_ticks, e.right_ticks) for e in expected]
    assert_same_poses([g.pose for g in got], [e.pose for e in expected], run.drive)
    assert stats.malformed == 8
    assert stats.reasons == {
        "missing checksum": 2,
        "bad byte": 1,
        "bad checksum": 2,
        "unknown record": 1,
        "too long": 1,
        "time not advancing": 1,
    }


def test_configured_geometry_wins_over_the_bridges(
    run: SimRun, pty: Pty, caplog: pytest.LogCaptureFixture
) -> None:
    master, path = pty.master, pty.path
    sim = SimOdometry(run)
    configured = DiffDrive(wheel_diameter_m=0.154, tread_m=0.40, ticks_per_turn=2000)
    decoder = EncoderDecoder(configured)
    expected = [r for host, rec in sim.records() if (r := decoder.feed(rec, host)) is not None]
    caplog.set_level(logging.WARNING, logger="robot_agent.sensors.encoders")
    with SerialOdometry(path, drive=configured) as source:  # no handshake: it only says '?'
        # this bridge streams without waiting and answers the '?' between two lines
        with BridgeEmulator(master, sim.lines(), info=sim.info):
            got = list(itertools.islice(source, len(expected)))
        assert source.drive is configured
        assert source.stats.info == sim.info
    assert [g.pose for g in got] == [e.pose for e in expected]
    assert "using the configured" in caplog.text


def test_hello_is_repeated_until_a_booting_bridge_answers(run: SimRun, pty: Pty) -> None:
    master, path = pty.master, pty.path
    sim = SimOdometry(run)
    with (
        BridgeEmulator(master, sim.lines()[:5], info=sim.info, wait_for_hello=True, ignore_hellos=1) as em,
        SerialOdometry(path) as source,
    ):
        got = list(itertools.islice(source, 5))
    assert em.hellos >= 2 and len(got) == 5
    assert all(isinstance(g, OdometryReading) for g in got)


def test_a_silent_bridge_without_configured_geometry_is_a_clear_error(pty: Pty) -> None:
    path = pty.path
    source = SerialOdometry(path, hello_timeout_s=0.3)
    with pytest.raises(EncoderError, match=r"did not answer '\?' with an 'I <ticks_per_rev>.*configure"):
        source.open()
    with pytest.raises(EncoderError, match="geometry is unknown"):
        _ = source.drive


def test_a_missing_port_is_a_clear_error() -> None:
    with pytest.raises(EncoderError, match="/dev/linemap-no-such-port: cannot open it"):
        SerialOdometry("/dev/linemap-no-such-port", drive=DiffDrive(0.15, 0.4, 4096)).open()


def test_an_unplugged_bridge_ends_the_readings_with_an_error(run: SimRun, pty: Pty) -> None:
    master, path = pty.master, pty.path
    sim = SimOdometry(run)
    with SerialOdometry(path, drive=run.drive) as source:
        with BridgeEmulator(master, sim.lines()[:20]) as emulator:
            readings = iter(source)
            got = list(itertools.islice(readings, 20))
            assert emulator.done.wait(10.0)
        pty.hang_up()
        with pytest.raises(EncoderError, match="unplugged"):
            next(readings)
    assert len(got) == 20


def test_a_bridge_that_stops_sending_is_reported(run: SimRun, pty: Pty) -> None:
    master, path = pty.master, pty.path
    sim = SimOdometry(run)
    with (
        SerialOdometry(path, drive=run.drive, stall_timeout_s=0.3) as source,
        BridgeEmulator(master, [*sim.lines()[:3], b"E 1 2\n"]),
    ):
        readings = iter(source)
        assert len(list(itertools.islice(readings, 3))) == 3
        with pytest.raises(EncoderError, match=r"no reading for 0.3 s \(\d bad lines\)"):
            next(readings)


def test_checksums_can_be_required_from_the_first_line(run: SimRun, pty: Pty) -> None:
    master, path = pty.master, pty.path
    sim = SimOdometry(run)
    records = [rec for _, rec in sim.records()][:5]
    lines = [format_line(rec, with_checksum=i % 2 == 0) for i, rec in enumerate(records)]
    with SerialOdometry(path, drive=run.drive, require_checksum=True) as source:
        with BridgeEmulator(master, lines):
            got = list(itertools.islice(source, 3))
        assert source.stats.reasons == {"missing checksum": 2}
    assert [g.device_ms for g in got] == [records[0].device_ms, records[2].device_ms, records[4].device_ms]
