"""``linemap map --dxf/--pgm/--resolution``: every export of one run describes the same walls."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from shared.cli.main import app
from shared.export import read_dxf, read_geojson_segments, read_occupancy, read_svg_segments
from shared.export.occupancy import OCCUPIED
from tests.shared.cli.test_cli import linemap


def _wall_samples(segments: np.ndarray, step_m: float) -> np.ndarray:
    pts = []
    for x0, y0, x1, y1 in segments:
        t = np.linspace(0.0, 1.0, max(math.ceil(math.hypot(x1 - x0, y1 - y0) / step_m), 1) + 1)
        pts.append(np.column_stack([x0 + t * (x1 - x0), y0 + t * (y1 - y0)]))
    return np.vstack(pts)


def test_map_sim_writes_dxf_occupancy_and_svg_of_the_same_walls(tmp_path: Path) -> None:
    """A real subprocess of the installed ``linemap``, as a user runs it."""
    run = linemap(
        "map", "sim", "--limit", "80", "--out", "m.geojson", "--svg", "m.svg",
        "--dxf", "m.dxf", "--pgm", "m", "--resolution", "0.05",
        cwd=tmp_path,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    for name in ("m.geojson", "m.svg", "m.dxf", "m.pgm", "m.yaml"):
        assert f"wrote {name}" in run.stdout
    walls = read_dxf(tmp_path / "m.dxf").segments
    assert len(walls) > 0
    geojson = read_geojson_segments(tmp_path / "m.geojson")
    assert np.abs(geojson - walls).max() <= 1e-9  # GeoJSON keeps 9 decimals, DXF all 17 digits
    np.testing.assert_array_equal(read_svg_segments(tmp_path / "m.svg").segments, walls)
    grid = read_occupancy(tmp_path / "m.yaml")
    assert grid.resolution_m == 0.05 and grid.origin[2] == 0.0
    assert all(abs(v / 0.05 - round(v / 0.05)) < 1e-6 for v in grid.origin[:2])  # whole cells from 0
    occupied = np.pad(grid.pixels == OCCUPIED, 1)
    row, col = grid.world_to_pixel(_wall_samples(walls, 0.005))
    near = np.zeros(len(row), dtype=bool)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            near |= occupied[row + 1 + dr, col + 1 + dc]
    assert near.all(), "every wall sample falls on an occupied cell, within one cell"


runner = CliRunner()


@pytest.mark.parametrize("bad", ["0", "-0.05", "nan", "inf"])
def test_bad_resolution_is_refused_before_mapping(tmp_path: Path, bad: str) -> None:
    result = runner.invoke(
        app,
        [
            "map",
            "sim",
            "--out",
            str(tmp_path / "m.geojson"),
            "--pgm",
            str(tmp_path / "m"),
            "--resolution",
            bad,
        ],
    )
    assert result.exit_code == 2
    assert f"--resolution {float(bad)}: expected metres per pixel > 0" in " ".join(result.stderr.split())
    assert "Traceback" not in result.output
    assert list(tmp_path.iterdir()) == []  # nothing mapped, nothing written


def test_resolution_that_is_not_a_number_is_a_usage_error(tmp_path: Path) -> None:
    result = runner.invoke(app, ["map", "sim", "--pgm", str(tmp_path / "m"), "--resolution", "fine"])
    assert result.exit_code == 2 and "--resolution" in result.stderr


def test_yaml_path_and_resolution_are_honoured(tmp_path: Path) -> None:
    out, grid = str(tmp_path / "m.geojson"), str(tmp_path / "grid.yaml")
    result = runner.invoke(
        app, ["map", "sim", "--limit", "40", "--out", out, "--pgm", grid, "--resolution", "0.1"]
    )
    assert result.exit_code == 0, result.output
    assert (tmp_path / "grid.pgm").is_file()
    assert read_occupancy(tmp_path / "grid.yaml").resolution_m == 0.1


def test_empty_map_and_unwritable_paths_are_one_clear_line(tmp_path: Path) -> None:
    # erosion on single online scans removes every point (README): a run that maps no wall
    config = tmp_path / "erode.json"
    config.write_text('{"noise_removal": [{"name": "erosion"}]}', encoding="utf-8")
    out = str(tmp_path / "m.geojson")
    empty = runner.invoke(
        app,
        ["map", "sim", "--limit", "5", "--config", str(config), "--out", out, "--pgm", str(tmp_path / "m")],
    )
    assert empty.exit_code == 2
    assert "the map has no walls" in " ".join(empty.stderr.split()) and "Traceback" not in empty.output
    assert not (tmp_path / "m.pgm").exists() and not (tmp_path / "m.yaml").exists()
    missing = tmp_path / "no" / "such" / "m.dxf"
    nowhere = runner.invoke(app, ["map", "sim", "--limit", "5", "--out", out, "--dxf", str(missing)])
    assert nowhere.exit_code == 2
    # rich folds a long line anywhere, also inside the path: compare without whitespace
    assert f"cannotwrite{missing}" in "".join(nowhere.stderr.split()) and "Traceback" not in nowhere.output


def test_map_a_rosbag2_mcap_with_a_chosen_topic_and_write_mcap(tmp_path: Path) -> None:
    """``linemap map BAG --topic T --mcap OUT`` as a user runs it: a rosbag2 MCAP bag with two LaserScan
    topics is refused without ``--topic`` (the error names both), mapped with it like the same scans from
    a CARMEN log, and the map comes back out of the MCAP file it wrote."""
    from shared.export import read_map_mcap
    from shared.io import write_carmen
    from shared.sim import default_world, simulate_run
    from tests.shared.io.test_io_rosbag import Bag, odometry_at_scans, write_bag

    scans = simulate_run(default_world(), seed=0).scans[:60]
    bag = write_bag(
        tmp_path / "run",
        "mcap",
        Bag({"/scan": scans, "/scan_rear": scans[:5]}, odometry=odometry_at_scans(scans)),
    )
    refused = linemap("map", str(bag), "--out", "m.geojson", cwd=tmp_path)
    assert refused.returncode == 2
    assert "/scan" in refused.stderr and "/scan_rear" in refused.stderr and "--topic" in refused.stderr
    assert "Traceback" not in refused.stderr
    run = linemap(
        "map", str(bag), "--topic", "/scan", "--odom-topic", "/odom", "--out", "m.geojson",
        "--mcap", "m.mcap", cwd=tmp_path,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    assert "wrote m.mcap" in run.stdout
    walls = read_geojson_segments(tmp_path / "m.geojson")
    assert len(walls) > 0
    back = read_map_mcap(tmp_path / "m.mcap")
    assert np.abs(back.segments - walls).max() <= 1e-9
    assert len(back.trajectory) == len(scans)
    write_carmen(tmp_path / "run.clf", scans)
    carmen = linemap("map", str(tmp_path / "run.clf"), "--out", "c.geojson", cwd=tmp_path)
    assert carmen.returncode == 0, carmen.stderr
    ref = read_geojson_segments(tmp_path / "c.geojson")
    assert abs(len(ref) - len(walls)) <= max(1, len(ref) // 10)
