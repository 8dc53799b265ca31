"""``linemap map`` on a log that holds no scan (empty, garbage bytes, a valid header or container with no
laser record) exits non-zero with "no scans found in FILE: expected ..." naming what its reader reads; it
never writes an empty map. Real subprocesses, real files, one case per reader the CLI dispatches to."""

from __future__ import annotations

import os
from collections.abc import Callable
from pathlib import Path

import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.typesys import Stores, get_typestore

from tests.shared.cli.test_cli import linemap

GARBAGE = bytes(range(256)) * 8 + os.urandom(512)


def _bag_without_scans(path: Path) -> None:
    """A valid ROS 1 bag with a LaserScan topic but no message on it (and one odometry message)."""
    ts = get_typestore(Stores.ROS1_NOETIC)
    with Writer1(path) as writer:
        writer.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=ts)
        odom = writer.add_connection("/odom", "std_msgs/msg/String", typestore=ts)
        msg = ts.types["std_msgs/msg/String"](data="not a scan")
        writer.write(odom, 1, ts.serialize_ros1(msg, "std_msgs/msg/String"))


CASES: dict[str, tuple[str, Callable[[Path], object], str]] = {
    "carmen-empty": ("run.clf", lambda p: p.write_bytes(b""), "CARMEN"),
    "carmen-garbage": ("run.log", lambda p: p.write_bytes(GARBAGE), "CARMEN"),
    "carmen-words": ("run.log", lambda p: p.write_text("hello world\nnot a record\n"), "CARMEN"),
    "carmen-header-only": (
        "run.clf",
        lambda p: p.write_text(
            "# CARMEN Logfile\nPARAM robot_front_laser_max 50\nODOM 0 0 0 0 0 0 1.0 h 1.0\n"
        ),
        "CARMEN",
    ),
    "breezyslam-empty": ("exp.dat", lambda p: p.write_bytes(b""), "BreezySLAM"),
    "breezyslam-garbage": ("exp.dat", lambda p: p.write_bytes(GARBAGE), "BreezySLAM"),
    "breezyslam-blank-lines": ("exp.dat", lambda p: p.write_text("\n\n   \n"), "BreezySLAM"),
    "rosbag-empty": ("run.bag", lambda p: p.write_bytes(b""), "ROS bag"),
    "rosbag-garbage": ("run.mcap", lambda p: p.write_bytes(GARBAGE), "ROS bag"),
    "rosbag-no-scans": ("run.bag", _bag_without_scans, "ROS bag"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_a_log_without_scans_exits_non_zero_naming_the_file_and_the_format(tmp_path: Path, case: str) -> None:
    name, write, fmt = CASES[case]
    log = tmp_path / name
    write(log)
    out = tmp_path / "map.geojson"
    run = linemap("map", str(log), "--out", str(out))
    assert run.returncode != 0, run.stdout + run.stderr
    text = " ".join((run.stdout + run.stderr).split())  # rich wraps long lines
    assert "Traceback" not in text, text
    if case == "rosbag-no-scans" and "no scans found" not in text:
        assert "LaserScan" in text and str(log.name) in text, text  # the bag reader names the missing topic
    else:
        assert f"no scans found in {log}" in text and f"expected a {fmt}" in text, text
    assert not out.exists(), "no empty map is written"
