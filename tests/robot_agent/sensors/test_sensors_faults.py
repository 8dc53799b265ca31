"""Faults injected into the emulated URG-04LX, survived by the driver: a garbled checksum or a truncated
frame loses that frame only; an unplug and replug (the device path disappears and comes back) loses no
scan at all; a silent sensor is reopened after the read timeout. Each test asserts which scans arrive."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from robot_agent.sensors.emulator import UrgEmulator
from robot_agent.sensors.urg import UrgDriver
from robot_agent.sensors.urg_model import Fault
from shared.sim import SimRun
from shared.types import Scan
from tests.robot_agent.sensors.urgtools import SAFETY_S, ScanIndex, consume, wait_until

N = 30


@pytest.mark.parametrize("fault", ["checksum", "truncate"])
def test_a_damaged_frame_is_dropped_and_the_stream_goes_on(
    fault: Fault, sim_run: SimRun, tmp_path: Path
) -> None:
    index = ScanIndex(sim_run.scans)
    with (
        UrgEmulator(sim_run.scans, link=tmp_path / "ttyURG", schedule={5: fault, 17: fault}) as emu,
        UrgDriver(emu.path) as urg,
    ):
        stream = urg.scans()
        got = [index(next(stream)) for _ in range(N - 2)]
        stream.close()
        assert urg.stats.dropped_frames == 2 and urg.stats.reconnects == 0
    assert [f.frame_no for f in emu.frames if f.fault == fault] == [5, 17]
    assert got == [i for i in range(N) if i not in (5, 17)]


@pytest.mark.parametrize("fault", ["checksum", "truncate"])
def test_faults_injected_on_demand_lose_exactly_the_faulty_frame(
    fault: Fault, sim_run: SimRun, tmp_path: Path
) -> None:
    index = ScanIndex(sim_run.scans)
    with UrgEmulator(sim_run.scans, link=tmp_path / "ttyURG") as emu, UrgDriver(emu.path) as urg:
        stream = urg.scans()
        got = [index(next(stream)) for _ in range(5)]
        emu.inject(fault)
        got += [index(next(stream)) for _ in range(10)]
        stream.close()
        faulty = [f.scan_index for f in emu.frames if f.fault is not None]
        assert len(faulty) == 1 and urg.stats.dropped_frames == 1
    assert got == [i for i in range(16) if i not in faulty]


def test_unplug_and_replug_on_a_schedule_loses_no_scan(sim_run: SimRun, tmp_path: Path) -> None:
    index = ScanIndex(sim_run.scans)
    with (
        UrgEmulator(
            sim_run.scans, link=tmp_path / "ttyURG", schedule={8: "unplug"}, replug_after_s=0.2
        ) as emu,
        UrgDriver(emu.path, backoff_s=0.02) as urg,
    ):
        stream = urg.scans()
        got = [index(next(stream)) for _ in range(N)]
        stream.close()
        assert urg.stats.reconnects == 1 and urg.stats.dropped_frames == 0
        assert emu.plugs == 2
    assert got == list(range(N))


def test_a_replug_at_the_same_path_is_found_and_the_stream_restarts(sim_run: SimRun, tmp_path: Path) -> None:
    """Unplugged while streaming: the path disappears (the driver's reopen attempts fail) until the
    replug puts a new pty behind the same link; the sensor boots in SCIP 1.1 again and is switched again."""
    index = ScanIndex(sim_run.scans)
    link = tmp_path / "ttyURG"
    with UrgEmulator(sim_run.scans, link=link, scip1_boot=True) as emu:
        first_tty = emu.tty_name
        urg = UrgDriver(emu.path, backoff_s=0.01, backoff_max_s=0.05)
        with urg, consume(urg) as c:
            got = [index(s) for s in c.take(10)]
            emu.unplug()
            assert not link.exists()
            wait_until("failed reopens", lambda: urg.stats.open_failures >= 2)  # it keeps trying meanwhile
            emu.replug()
            got += [index(s) for s in c.take(15)]
            assert emu.tty_name is not None and link.resolve() == Path(emu.tty_name)
            assert urg.switched_from_scip1 and urg.stats.reconnects == 1
        assert emu.plugs == 2 and first_tty is not None
    # a frame written but not yet read when the pty closed is sent again after the replug
    assert len([f for f in emu.frames if f.fault == "unread"]) <= 1
    assert got == list(range(25))


def test_a_sensor_that_falls_silent_is_reopened_after_the_read_timeout(
    sim_run: SimRun, tmp_path: Path
) -> None:
    """The sensor hangs before its 11th scan (it answers nothing); the driver's read times out, its
    reopen attempts time out too, and once the sensor answers again the stream goes on, in order, with
    nothing lost after the restart. Which scans the sensor sends while the driver is still reopening (its
    old stream runs until the driver's QT) depends on timing: those are skipped, as on a real port."""
    index = ScanIndex(sim_run.scans)
    resume = threading.Event()

    def hanging() -> Iterator[Scan]:
        for i, scan in enumerate(sim_run.scans):
            if i == 10:
                resume.wait(SAFETY_S)
            yield scan

    with UrgEmulator(hanging(), link=tmp_path / "ttyURG") as emu:
        urg = UrgDriver(emu.path, timeout_s=0.3, backoff_s=0.01, backoff_max_s=0.05)
        with urg, consume(urg) as c:
            got = [index(s) for s in c.take(10)]
            wait_until("a read timeout", lambda: "no scan frame within" in urg.stats.last_error)
            resume.set()
            got += [index(s) for s in c.take(10)]
            assert urg.stats.reconnects == 1 and urg.stats.dropped_frames == 0
    assert got[:10] == list(range(10))
    assert got[10] >= 10 and got[10:] == list(range(got[10], got[10] + 10))
