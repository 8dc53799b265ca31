"""``linemap bench worlds`` as a user runs it (a real subprocess, real files)."""

from __future__ import annotations

import json
from pathlib import Path

from shared.sim.worlds import KINDS, QUICK_KINDS
from tests.shared.cli.test_cli import linemap


def test_bench_worlds_quick_runs_end_to_end(tmp_path: Path) -> None:
    out, pics = tmp_path / "worlds.json", tmp_path / "pics"
    run = linemap("bench", "worlds", "--quick", "--json", str(out), "--out", str(pics))
    assert run.returncode == 0, run.stderr
    for kind in QUICK_KINDS:
        assert kind in run.stdout
    assert "summary (3 cases" in run.stdout and "odometry ATE m" in run.stdout
    doc = json.loads(out.read_text())
    assert [r["kind"] for r in doc["results"]] == list(QUICK_KINDS)
    for r in doc["results"]:
        assert r["scans"] == 150 and 0.0 <= r["completeness"] <= 1.0 and r["walls_seen"] >= 1
        assert r["ate_m"] >= 0.0 and r["odometry_ate_m"] >= 0.0 and r["scans_per_s"] > 0
    assert doc["summary"]["cases"] == 3
    assert sorted(p.name for p in pics.iterdir()) == sorted(f"{k}-0.png" for k in QUICK_KINDS)
    assert (pics / f"{QUICK_KINDS[0]}-0.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bench_worlds_lists_its_kinds_and_refuses_unknown_ones() -> None:
    listed = linemap("bench", "worlds", "--list")
    assert listed.returncode == 0 and all(k in listed.stdout for k in KINDS)
    bad = linemap("bench", "worlds", "--worlds", "corridor-long,moon")
    assert bad.returncode == 2 and "moon" in bad.stderr and "Traceback" not in bad.stderr
    odo = linemap("bench", "worlds", "--worlds", "corridor-long", "--odometry", "teleport")
    assert odo.returncode == 2 and "odometry model" in odo.stderr
