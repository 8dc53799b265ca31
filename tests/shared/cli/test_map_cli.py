"""``linemap map`` and ``linemap eval`` as a user runs them (real subprocesses, real files)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from tests.shared.cli.test_cli import ROOT, linemap

DATA = ROOT.parent / "shared" / "data"


def test_map_sim_writes_the_contracted_outputs(tmp_path: Path) -> None:
    out, png, traj = tmp_path / "m.geojson", tmp_path / "m.png", tmp_path / "t.csv"
    run = linemap(
        "map", "sim", "--limit", "80", "--out", str(out), "--png", str(png), "--trajectory-out", str(traj)
    )
    assert run.returncode == 0, run.stderr
    assert "accuracy against the ground truth" in run.stdout and "scans/s" in run.stdout
    doc = json.loads(out.read_text())
    assert doc["type"] == "FeatureCollection"
    segments = [f for f in doc["features"] if f["properties"]["kind"] == "segment"]
    assert segments
    for feature in segments:
        coords = feature["geometry"]["coordinates"]
        assert feature["geometry"]["type"] == "LineString" and len(coords) == 2
        assert all(len(p) == 2 for p in coords)
    with traj.open() as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["stamp", "x", "y", "theta"] and len(rows) == 81
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    ev = linemap(
        "eval", str(out), "--walls", "sim", "--trajectory", str(traj), "--json", str(tmp_path / "e.json")
    )
    assert ev.returncode == 0, ev.stderr
    figures = json.loads((tmp_path / "e.json").read_text())
    assert figures["line_accuracy"]["mean_distance_m"] < 0.05


@pytest.mark.skipif(
    not (DATA / "breezyslam-urg04lx").is_dir(), reason="../shared/data is not beside the repo"
)
def test_map_real_urg_log(tmp_path: Path) -> None:
    log = DATA / "breezyslam-urg04lx" / "exp1.dat.gz"
    run = linemap("map", str(log), "--limit", "100", "--out", str(tmp_path / "m.geojson"))
    assert run.returncode == 0, run.stderr
    assert "breezyslam log exp1.dat.gz" in run.stdout


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["map", "no/such/log.clf"], "not found"),
        (["map", "sim", "--config", "control.xml"], "control.xml"),
        (["map", "sim:missing-world.toml"], "missing-world.toml"),
        (["eval", "missing.geojson", "--walls", "sim"], "missing.geojson"),
        (["eval", "x.geojson"], "nothing to measure against"),
    ],
)
def test_errors_are_one_clear_line(args: list[str], message: str, tmp_path: Path) -> None:
    (tmp_path / "control.xml").write_text("<xml/>")
    run = linemap(*args, cwd=tmp_path)
    assert run.returncode == 2
    assert message in " ".join(run.stderr.split()) and "Traceback" not in run.stderr


def test_bad_json_config_names_the_field(tmp_path: Path) -> None:
    cfg = tmp_path / "c.json"
    cfg.write_text(json.dumps({"mode": "sideways"}))
    run = linemap("map", "sim", "--limit", "5", "--config", str(cfg), "--out", str(tmp_path / "m.geojson"))
    assert run.returncode == 2 and "mode" in run.stderr and "Traceback" not in run.stderr


def test_broken_log_keeps_the_map_of_the_good_scans(tmp_path: Path) -> None:
    from shared.io import write_carmen
    from shared.sim import default_world, simulate_run

    run = simulate_run(default_world(), seed=3)
    log = tmp_path / "run.clf"
    write_carmen(log, run.scans[:60], laser_offset=run.drive.laser_offset)
    lines = log.read_text().splitlines()
    laser_lines = [i for i, line in enumerate(lines) if line.startswith(("FLASER", "ROBOTLASER1"))]
    bad = laser_lines[40]
    lines[bad] = lines[bad].split()[0] + " 3 1.0 2.0"
    log.write_text("\n".join(lines) + "\n")
    out = tmp_path / "m.geojson"
    result = linemap("map", str(log), "--out", str(out))
    assert result.returncode == 2
    message = " ".join(result.stderr.split())
    assert f"line {bad + 1}" in message and "40 good scans" in message
    assert json.loads(out.read_text())["type"] == "FeatureCollection", "the partial map is written"


def test_listing1_as_config(tmp_path: Path) -> None:
    listing = ROOT / "tests" / "shared" / "control" / "fixtures" / "listing1.xml"
    run = linemap(
        "map", "sim", "--limit", "30", "--config", str(listing), "--out", str(tmp_path / "m.geojson")
    )
    assert run.returncode == 0, run.stderr
    assert (tmp_path / "m.geojson").exists()
