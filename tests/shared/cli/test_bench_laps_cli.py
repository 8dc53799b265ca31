"""``linemap bench laps`` as a user runs it (a real subprocess, real files)."""

from __future__ import annotations

import json
from pathlib import Path

from tests.shared.cli.test_cli import linemap


def test_bench_laps_runs_end_to_end(tmp_path: Path) -> None:
    png, out = tmp_path / "fig20.png", tmp_path / "laps.json"
    run = linemap("bench", "laps", "--seeds", "2", "--laps", "1", "--png", str(png), "--json", str(out))
    assert run.returncode == 0, run.stderr
    assert "front end" in run.stdout and "loop closure" in run.stdout
    assert "pose-graph optimisations" in run.stdout
    doc = json.loads(out.read_text())
    assert [(d["seed"], d["variant"]) for d in doc] == [(2, "front end"), (2, "loop closure")]
    for d in doc:
        (lap,) = d["laps"]
        assert lap["lap"] == 1 and lap["walls_seen"] > 0 and 0.0 <= lap["completeness"] <= 1.0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bench_laps_refuses_bad_options(tmp_path: Path) -> None:
    bad = linemap("bench", "laps", "--world", "moon")
    assert bad.returncode == 2 and "moon" in bad.stderr and "Traceback" not in bad.stderr
    seeds = linemap("bench", "laps", "--seeds", "x")
    assert seeds.returncode == 2 and "--seeds" in seeds.stderr
    nowhere = linemap("bench", "laps", "--png", str(tmp_path / "no" / "such" / "f.png"))
    assert nowhere.returncode == 2 and "does not exist" in " ".join(nowhere.stderr.split())
