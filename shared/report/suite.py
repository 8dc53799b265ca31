"""The report's scenario-suite section (docs/worlds.md): every kind of world and seed of
:mod:`shared.sim.worlds` mapped and measured exactly as ``linemap bench worlds`` does
(:func:`shared.bench.worlds.run_case`), its table and summary, and a grid of small maps, one per kind.

The quick report takes the suite's ``--quick`` path (:data:`QUICK_KINDS`, the first seed, at most
:data:`QUICK_MAX_SCANS` scans per case). :func:`suite_document` is the section as a file of its own
(``worlds.md``), which the README cites for its accuracy figures.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from shared.bench.worlds import QUICK_MAX_SCANS, WorldResult, run_case, summarize
from shared.metrics.distance import nearest_segment
from shared.sim.worlds import KINDS, QUICK_KINDS, simulate_case
from shared.types import FloatArray

__all__ = [
    "GRID_PNG",
    "SuiteMap",
    "SuiteRun",
    "run_suite",
    "segment_errors_m",
    "suite_command",
    "suite_document",
    "suite_section",
]

#: The grid of maps beside the report.
GRID_PNG = "worlds_maps.png"
#: Colour bands of a mapped wall by its mean distance to the true walls (m): on the wall, near, spurious.
ERROR_BANDS_M = (0.05, 0.10)


@dataclass(frozen=True)
class SuiteMap:
    """One case's map for the grid: true walls at the end of the run ``(W, 4)``, mapped walls ``(L, 4)``
    and the pipeline's trajectory ``(T, 4)`` rows ``[stamp_s, x_m, y_m, theta_rad]`` (m)."""

    truth: FloatArray
    segments: FloatArray
    trajectory: FloatArray


@dataclass(frozen=True)
class SuiteRun:
    """The suite's figures per case (suite order) and, per kind, the map of its first seed."""

    seeds: tuple[int, ...]
    quick: bool
    results: list[WorldResult]
    maps: dict[str, SuiteMap] = field(default_factory=dict)
    seconds: float = 0.0


def run_suite(
    seeds: Sequence[int], *, quick: bool = False, progress: Callable[[str], None] | None = None
) -> SuiteRun:
    """Map every case of the suite (``quick``: the ``--quick`` subset, first seed only) and keep the
    first seed's map of each kind. Minutes for the whole suite; O(cases x scans x step)."""
    import time

    say = progress or (lambda _m: None)
    kinds = list(QUICK_KINDS if quick else KINDS)
    used = tuple(seeds[:1]) if quick else tuple(seeds)
    cases = [(k, s) for k in kinds for s in used]
    results: list[WorldResult] = []
    maps: dict[str, SuiteMap] = {}
    t0 = time.perf_counter()
    for i, (kind, seed) in enumerate(cases):
        say(f"scenario suite: {kind} seed {seed} ({i + 1}/{len(cases)})")
        case = simulate_case(kind, seed, max_scans=QUICK_MAX_SCANS if quick else None)
        result, mapped = run_case(case)
        results.append(result)
        if kind not in maps:
            snap = mapped.snapshot
            maps[kind] = SuiteMap(case.truth.walls, snap.segments, snap.trajectory)
    return SuiteRun(used, quick, results, maps, time.perf_counter() - t0)


def suite_command(run: SuiteRun) -> str:
    """The ``linemap bench worlds`` command that measures the same cases."""
    if run.quick:
        return "linemap bench worlds --quick"
    return f"linemap bench worlds --seeds {','.join(map(str, run.seeds))}"


def segment_errors_m(segments: FloatArray, walls: FloatArray, samples: int = 5) -> FloatArray:
    """Mean distance (m) of each mapped segment ``(L, 4)`` to the nearest true wall, over ``samples``
    points spread along it. O(L x samples x log W)."""
    segs = np.asarray(segments, dtype=np.float64).reshape(-1, 4)
    if len(segs) == 0:
        return np.zeros(0)
    t = np.linspace(0.0, 1.0, samples)[None, :, None]
    pts = segs[:, None, :2] + t * (segs[:, None, 2:] - segs[:, None, :2])
    dist, _ = nearest_segment(pts.reshape(-1, 2), np.asarray(walls, dtype=np.float64).reshape(-1, 4))
    return np.asarray(dist.reshape(len(segs), samples).mean(axis=1))


def _pct(x: float) -> str:
    return "n/a" if not math.isfinite(x) else f"{100 * x:.1f} %"


def _cm(x: float) -> str:
    return "n/a" if not math.isfinite(x) else f"{100 * x:.2f} cm"


def suite_section(run: SuiteRun, grid: str | None = GRID_PNG) -> list[str]:
    """The section's Markdown lines: what ran, the summary in words, the table, the grid of maps."""
    from shared.bench.tables import worlds_markdown

    s = summarize(run.results)
    n = int(s.get("cases", 0))
    out = [
        "## Scenario suite",
        "",
        f"Every kind of world of the scenario suite ({len({r.kind for r in run.results})} kinds x "
        f"{'seed' if len(run.seeds) == 1 else 'seeds'} {', '.join(map(str, run.seeds))}"
        + (f", at most {QUICK_MAX_SCANS} scans each: the suite's --quick subset" if run.quick else "")
        + "), each with its own odometry error model and driving pattern, mapped offline with the default "
        f"`PipelineConfig` as `{suite_command(run)}` maps it (docs/worlds.md says what the worlds hold "
        "and how the figures are measured). The suite's targets (single pass): mean wall error <= 2 cm, "
        "completeness of the seen walls >= 95 %, spurious share <= 3 %, walls mapped <= 1.5 x true walls "
        "seen; trajectory error (ATE) no worse than odometry's.",
        "",
    ]
    if n == 0:
        return [*out, "No case ran.", ""]
    ate, odo = float(s["ate_m"]), float(s["odometry_ate_m"])
    better = sum(r.ate_m <= r.odometry_ate_m for r in run.results)
    out += [
        f"**{s['cases_meeting_targets']} of {n} cases** meet all four map targets. Over the cases: mean wall "
        f"error {_cm(float(s['mean_error_m']))} (worst case {_cm(float(s['worst_mean_error_m']))}), p95 "
        f"{_cm(float(s['p95_error_m']))}; completeness {_pct(float(s['completeness']))} (worst "
        f"{_pct(float(s['worst_completeness']))}); spurious share {_pct(float(s['spurious_share']))} "
        f"(worst {_pct(float(s['worst_spurious_share']))}); {float(s['wall_ratio']):.2f} walls mapped per "
        f"true wall seen; ATE {ate:.3f} m against odometry's {odo:.3f} m on average, no worse than "
        f"odometry's in {better} of {n} cases; median "
        f"{float(s['scans_per_s']):,.0f} scans/s (reading included; {run.seconds / 60:.1f} min in all).",
        "",
        worlds_markdown(run.results).rstrip("\n"),
        "",
    ]
    if grid is not None and run.maps:
        out += [
            f"One map per kind (seed {run.seeds[0]}): true walls at the end of the run in grey, mapped walls "
            f"coloured by their mean distance to the nearest true wall (blue <= {ERROR_BANDS_M[0] * 100:.0f}"
            f" cm, orange <= {ERROR_BANDS_M[1] * 100:.0f} cm, red farther: spurious), the pipeline's "
            "trajectory in green.",
            "",
            f"![Scenario suite: one map per kind]({grid})",
            "",
        ]
    return out


def suite_document(run: SuiteRun, command: str, started: str, versions: dict[str, str]) -> str:
    """The section as a document of its own (``worlds.md``), with when and by which command it was made."""
    v = versions
    head = [
        "# The scenario suite: latest generated run",
        "",
        f"Generated {started} by `{command}` at commit {v.get('commit', 'unknown')} (linemap "
        f"{v.get('linemap', '?')}, Python "
        f"{v.get('python', '?')}, NumPy {v.get('numpy', '?')}, numba {v.get('numba', '?')}; "
        f"{v.get('machine', '?')}). The same cases and figures as `{suite_command(run)}`; throughput "
        "depends on the machine's load (compare it only within one run).",
        "",
    ]
    return "\n".join([*head, *suite_section(run)]) + "\n"
