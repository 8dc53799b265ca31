"""The report's scenario-suite section: the same cases and figures as ``linemap bench worlds`` (its
``--quick`` path in the quick report), a summary in words computed from the table's numbers, a grid of
maps, and ``worlds.md`` written on its own by ``linemap report --worlds-only``."""

from __future__ import annotations

import dataclasses
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from shared.bench.worlds import QUICK_MAX_SCANS, WorldResult, run_worlds
from shared.report.suite import SuiteRun, run_suite, segment_errors_m, suite_document, suite_section
from shared.sim.worlds import QUICK_KINDS

LINEMAP = str(Path(sys.executable).parent / "linemap")


def _result(kind: str, seed: int, mean_m: float, complete: float, walls: int) -> WorldResult:
    return WorldResult(
        kind,
        seed,
        "slip",
        "single",
        100,
        mean_m,
        2 * mean_m,
        complete,
        0.01,
        walls,
        10,
        0.05,
        0.08,
        250.0,
        1.0,
    )


def test_the_section_states_the_summary_of_its_own_table() -> None:
    good, bad = _result("corridor-long", 0, 0.01, 0.97, 12), _result("office-l", 0, 0.12, 0.5, 30)
    text = "\n".join(suite_section(SuiteRun((0,), False, [good, bad])))
    assert "## Scenario suite" in text
    assert "**1 of 2 cases** meet all four map targets" in text
    assert "mean wall error 6.50 cm (worst case 12.00 cm)" in text
    assert "ATE 0.050 m against odometry's 0.080 m on average, no worse than odometry's in 2 of 2" in text
    assert "| corridor-long | 0 | slip | single | 100 | 1.00 |" in text
    assert "| summary (2 cases, 1 on target) |" in text
    assert "`linemap bench worlds --seeds 0`" in text
    empty = "\n".join(suite_section(SuiteRun((0,), True, [])))
    assert "No case ran." in empty and "nan" not in empty


def test_segment_errors_are_distances_to_the_nearest_true_wall() -> None:
    walls = np.array([[0.0, 0.0, 10.0, 0.0], [0.0, 0.0, 0.0, 5.0]])
    segs = np.array([[1.0, 0.03, 4.0, 0.03], [0.5, 1.0, 0.5, 3.0], [2.0, 0.0, 2.0, 0.2]])
    got = segment_errors_m(segs, walls)
    assert np.allclose(got, [0.03, 0.5, 0.1])  # the crossing stub: 0, .05, .1, .15, .2 m off the wall
    assert segment_errors_m(np.zeros((0, 4)), walls).shape == (0,)


@given(st.floats(-5, 5), st.floats(-5, 5), st.floats(0, 2 * math.pi), st.floats(0.1, 3), st.floats(-0.5, 0.5))
def test_a_segment_parallel_to_a_wall_is_as_far_as_its_offset(
    x: float, y: float, theta: float, length: float, offset: float
) -> None:
    d, n = np.array([math.cos(theta), math.sin(theta)]), np.array([-math.sin(theta), math.cos(theta)])
    wall = np.array([[*(np.array([x, y]) - 10 * d), *(np.array([x, y]) + 10 * d)]])
    p0 = np.array([x, y]) + offset * n
    seg = np.array([[*p0, *(p0 + length * d)]])
    assert math.isclose(segment_errors_m(seg, wall)[0], abs(offset), abs_tol=1e-9)


def test_the_quick_section_is_the_suites_quick_path() -> None:
    ours = run_suite((0, 1, 2), quick=True)
    theirs = run_worlds(seeds=(0,), quick=True)  # as `linemap bench worlds --quick`
    assert [r.kind for r in ours.results] == list(QUICK_KINDS) and ours.seeds == (0,)
    assert all(r.scans <= QUICK_MAX_SCANS for r in ours.results)
    timing = {"scans_per_s", "step_median_ms"}
    for a, b in zip(ours.results, theirs, strict=True):
        fa, fb = dataclasses.asdict(a), dataclasses.asdict(b)
        assert {k: v for k, v in fa.items() if k not in timing} == {
            k: v for k, v in fb.items() if k not in timing
        }
    assert set(ours.maps) == set(QUICK_KINDS)
    for m in ours.maps.values():
        assert m.segments.shape[1] == 4 and len(m.trajectory) > 0 and len(m.truth) > 0
    doc = suite_document(ours, "linemap report --worlds-only --quick", "today", {"linemap": "0"})
    assert doc.startswith("# The scenario suite") and "`linemap report --worlds-only --quick`" in doc


def test_worlds_only_writes_the_section_and_its_maps_alone(tmp_path: Path) -> None:
    r = subprocess.run(
        [LINEMAP, "report", "--worlds-only", "--quick", "--out", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    text = (tmp_path / "worlds.md").read_text()
    assert "## Scenario suite" in text and "](worlds_maps.png)" in text
    assert all(f"| {kind} | 0 |" in text for kind in QUICK_KINDS)
    png = (tmp_path / "worlds_maps.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
    assert not (tmp_path / "report.md").exists()
    assert "note: no benchmark logs" not in r.stderr  # the suite needs no logs
