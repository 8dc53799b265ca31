"""``linemap report``: the quick version runs end to end and writes every section and figure; the
cluttered world is what it claims to be."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from shared.metrics.distance import nearest_segment
from shared.report.worlds import CLUTTER_NOISE, cluttered_world
from shared.sim import DEFAULT_KNOTS, default_world

ROOT = Path(__file__).resolve().parents[3]
DATA = ROOT.parent / "shared" / "data"
LINEMAP = str(Path(sys.executable).parent / "linemap")


def test_cluttered_world_keeps_the_room_and_clears_the_path() -> None:
    world, base = cluttered_world(), default_world()
    assert world.walls.shape[0] >= base.walls.shape[0] + 4 * 20  # at least 20 boxes of 4 walls
    assert np.array_equal(world.walls[: len(base.walls)], base.walls)
    assert world.floor_area_m2 < base.floor_area_m2
    knots = np.asarray(DEFAULT_KNOTS)
    path = np.linspace(knots[:-1], knots[1:], 50).reshape(-1, 2)
    dist, _ = nearest_segment(path, world.walls[len(base.walls) :])
    assert dist.min() >= 0.6, "the robot's path stays clear of every obstacle"
    assert CLUTTER_NOISE.outlier_rate == 0.10
    assert np.array_equal(cluttered_world().walls, world.walls), "deterministic"


def test_quick_report_writes_every_section_and_figure(tmp_path: Path) -> None:
    out = tmp_path / "report"
    # In a clone that is not beside ../shared/data the report leaves out the relation-error section and
    # says so; it must still write everything else.
    have_data = DATA.is_dir()
    data_args = ["--data", str(DATA)] if have_data else []
    env = {**os.environ, "LINEMAP_DATA": str(DATA if have_data else tmp_path / "absent")}
    r = subprocess.run(
        [LINEMAP, "report", "--quick", "--out", str(out), *data_args],
        env=env,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    text = (out / "report.md").read_text()
    for heading in (
        "## Table 3",
        "## Fig. 19",
        "## Fig. 24",
        "## Accuracy on simulated worlds",
        "## Scenario suite",
        "## Relation error on the SLAM benchmark logs",
        "## Multi-lap worlds: loop closure over time",
        "## Noise removal kernels",
    ):
        assert heading in text, heading
    for png in (
        "fig19_area_vs_clusters.png",
        "fig24_time_per_step.png",
        "maps_cluttered.png",
        "worlds_maps.png",
        "fig20_position_error.png",
    ):
        data = (out / png).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000, png
        assert f"]({png})" in text
    assert "linemap report --quick" in text and "numpy" in text.lower()
    if have_data:
        assert "| MIT CSAIL |" in text  # the smallest benchmark log, mapped by linemap
        assert "| log | scans | linemap | linemap + loop closure |" in text  # with and without the graph
    else:
        assert "Not run: the data folder was not found." in text
    assert "ekf-slam" in text and "cluttered" in text
    assert "`linemap bench worlds --quick`" in text  # the suite's quick path
    assert "## Scenario suite" in (out / "worlds.md").read_text()
    # the multi-lap section: both ways of mapping at each lap's end, and the optimisations' times
    assert "| loop-block | 0 | front end | 2 |" in text and "| loop-block | 0 | loop closure | 2 |" in text
    assert "pose-graph optimisations" in text and "map redraws" in text
    assert "nan" not in text.replace("nanoseconds", "")


def test_report_refuses_bad_options(tmp_path: Path) -> None:
    r = subprocess.run(
        [LINEMAP, "report", "--seeds", "a,b", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2 and "--seeds" in r.stderr and "Traceback" not in r.stderr
    r = subprocess.run(
        [LINEMAP, "report", "--data", str(tmp_path / "nope"), "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2 and "nope" in r.stderr and "Traceback" not in r.stderr
