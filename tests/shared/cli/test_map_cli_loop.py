"""``linemap map`` with loop closure as a user runs it (real subprocesses): the summary counts the loop
closures; a bad loop-closure setting is refused naming it, with no traceback."""

from __future__ import annotations

from pathlib import Path

from tests.shared.cli.test_cli import linemap


def test_the_summary_counts_loop_closures(tmp_path: Path) -> None:
    run = linemap("map", "sim", "--limit", "120", "--out", str(tmp_path / "m.geojson"))
    assert run.returncode == 0, run.stderr
    assert "loop closures" in run.stdout
    off = linemap("map", "sim", "--limit", "120", "--no-loop-closure", "--out", str(tmp_path / "n.geojson"))
    assert off.returncode == 0, off.stderr


def test_a_bad_loop_setting_is_refused_naming_it(tmp_path: Path) -> None:
    run = linemap(
        "map", "sim", "--limit", "20", "--loop-min-inliers", "2", "--out", str(tmp_path / "m.geojson")
    )
    assert run.returncode == 2
    assert "min_inlier_share" in run.stderr and "expected" in run.stderr
    assert "Traceback" not in run.stderr
    assert not (tmp_path / "m.geojson").exists()
