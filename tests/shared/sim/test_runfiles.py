"""Writing a simulated run: CARMEN log, world file and ground-truth CSVs that load back."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from shared.sim import (
    SimRun,
    WorldFileError,
    default_world,
    load_world,
    plan_path,
    read_poses,
    simulate_run,
    write_run,
)


@pytest.fixture(scope="module")
def run() -> SimRun:
    return simulate_run(default_world(), plan_path(np.array([[1.0, 3.0], [2.0, 3.0], [2.0, 3.4]])), seed=4)


@pytest.fixture(scope="module")
def written(run: SimRun, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    pytest.importorskip("shared.io.carmen", reason="shared.io.carmen (write_carmen) is not written yet")
    return write_run(run, tmp_path_factory.mktemp("run") / "nested" / "dir")


def test_files_and_names(written: dict[str, Path]) -> None:
    assert {k: p.name for k, p in written.items()} == {
        "clf": "run.clf",
        "walls": "walls.json",
        "poses": "poses.csv",
        "ticks": "ticks.csv",
    }
    assert all(p.is_file() and p.stat().st_size > 0 for p in written.values())


def test_world_and_poses_load_back(run: SimRun, written: dict[str, Path]) -> None:
    world = load_world(written["walls"])
    np.testing.assert_array_equal(world.walls, run.world.walls)
    assert world.floor_area_m2 == run.world.floor_area_m2 and world.name == run.world.name
    assert written["poses"].read_text().splitlines()[0] == "stamp,x,y,theta"
    np.testing.assert_array_equal(read_poses(written["poses"]), run.trajectory("true"))
    ticks = np.loadtxt(written["ticks"], delimiter=",", skiprows=1)
    np.testing.assert_array_equal(ticks[:, 1:], run.ticks)


def test_read_poses_names_the_bad_line(tmp_path: Path) -> None:
    path = tmp_path / "poses.csv"
    path.write_text("stamp,x,y,theta\n0.0,1,2,3\n0.1,1,2\n")
    with pytest.raises(WorldFileError, match=r"line 3: '0.1,1,2': expected 4 finite numbers"):
        read_poses(path)
    path.write_text("t,x,y\n")
    with pytest.raises(WorldFileError, match="expected the header"):
        read_poses(path)


def test_clf_opens_as_a_log(run: SimRun, written: dict[str, Path]) -> None:
    logs = pytest.importorskip("shared.io.logs", reason="shared.io.logs (open_log) is not written yet")
    with logs.open_log(written["clf"]) as log:
        scans = list(log)
        offset = log.info.laser_offset
    assert len(scans) == len(run.scans)
    assert offset.x_m == pytest.approx(run.drive.laser_offset.x_m)
    for got, want in zip(scans, run.scans, strict=True):
        assert got.stamp_s == pytest.approx(want.stamp_s, abs=1e-3)
        assert got.odometry is not None and want.odometry is not None
        assert got.odometry.x_m == pytest.approx(want.odometry.x_m, abs=1e-3)
        assert got.odometry.theta_rad == pytest.approx(want.odometry.theta_rad, abs=1e-3)
        np.testing.assert_array_equal(got.valid_mask(), want.valid_mask())
        valid = want.valid_mask()
        np.testing.assert_allclose(got.ranges_m[valid], want.ranges_m[valid], atol=1e-3)
