"""A full disk under the Robot DB (a real 16 MB tmpfs, filled to the last byte while a real agent maps and
uploads to a real server): the agent pauses recording instead of dying, the server's robot shows why in
``last_error``, nothing recorded is lost, and once the space is freed the agent records and delivers
every remaining version by itself, each once and in order."""

from __future__ import annotations

import errno
import os
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.robot_agent.agentproc import AgentProcess, robot_db_meta, wait_for
from tests.server.live import Live, start_live

STEPS = 400


@pytest.fixture
def small_disk(tmp_path: Path) -> Iterator[Path]:
    disk = tmp_path / "disk"
    disk.mkdir()
    done = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=16m", "tmpfs", str(disk)], capture_output=True, text=True
    )
    if done.returncode != 0:
        pytest.skip(f"mounting a small tmpfs needs root (CAP_SYS_ADMIN): {done.stderr.strip()}")
    try:
        yield disk
    finally:
        subprocess.run(["umount", "-l", str(disk)], check=False)


@pytest.fixture
def server(tmp_path: Path) -> Iterator[Live]:
    (tmp_path / "server").mkdir()
    yield from start_live("sqlite", tmp_path / "server")


def _fill(disk: Path) -> Path:
    """Write a file on ``disk`` until not one more byte fits."""
    filler = disk / "filler"
    with filler.open("wb", buffering=0) as f:
        for chunk in (1 << 20, 1 << 12, 1):
            try:
                while True:
                    f.write(b"\0" * chunk)
            except OSError as exc:
                if exc.errno != errno.ENOSPC:
                    raise
    return filler


def test_a_full_disk_pauses_recording_reports_it_and_recovers_when_space_returns(
    small_disk: Path, server: Live, tmp_path: Path
) -> None:
    rid, token = server.new_robot()
    db = small_disk / "robot.db"
    agent = AgentProcess(
        db,
        server=server.base_url,
        robot_id=rid,
        token=token,
        extra=["--rate", "20", "--max-steps", str(STEPS)],
        log=tmp_path / "agent.log",  # the log stays off the full disk
    )
    try:
        with server.operator() as op:
            # gated on the robot's own progress, not the server's: a server slow to take the first
            # uploads (a loaded machine) must not let the agent record every step before the disk fills
            wait_for(
                "the first versions recorded",
                lambda: (robot_db_meta(db, "map_version") or 0) >= 20,
                600,
            )
            filler = _fill(small_disk)
            before_fill = int(robot_db_meta(db, "map_version"))
            assert before_fill < STEPS, f"the agent recorded all {STEPS} steps before the disk was filled"
            robot = wait_for(
                "the robot to report its full disk",
                lambda: (
                    (r := op.get(f"/robots/{rid}").json())["last_error"]
                    and "recording paused" in r["last_error"]
                    and r
                ),
                120,
            )
            assert "recording paused at map version" in robot["last_error"], robot["last_error"]
            paused_at = int(robot["last_error"].split("recording paused at map version ")[1].split(",")[0])
            assert agent.proc.poll() is None, "the agent died on a full disk"
            recorded = int(robot_db_meta(db, "map_version"))
            assert paused_at == recorded + 1, (paused_at, recorded)  # the step waiting to be recorded
            # the server never holds more than the robot recorded (deliveries it could not note on the full
            # disk are sent again after: the server answers them as duplicates)
            assert op.get(f"/robots/{rid}").json()["map_version"] <= recorded
            os.unlink(filler)  # space returns
            wait_for(
                "every version delivered after the pause",
                lambda: op.get(f"/robots/{rid}").json()["map_version"] == STEPS,
                300,
            )
            stamps = [row[0] for row in op.get(f"/robots/{rid}/maps/latest").json()["trajectory"]]
        assert agent.stop() == 0
    finally:
        if agent.proc.poll() is None:
            agent.kill()
    assert len(stamps) == STEPS and stamps == sorted(set(stamps)), "each version once, in order"
    out = agent.output()
    assert "Traceback" not in out and "this is a bug" not in out
    assert "recording resumed" in out
