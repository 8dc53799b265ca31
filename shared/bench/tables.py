"""Benchmark figures as table rows and Markdown: the scenario suite's (``linemap bench worlds``, the
report's suite section) and the helper every Markdown table of the benchmarks uses."""

from __future__ import annotations

import math
from collections.abc import Sequence

from shared.bench.worlds import WorldResult, summarize

__all__ = ["WORLD_COLUMNS", "markdown_table", "worlds_markdown", "worlds_rows"]

#: A table's columns: (header, right-aligned).
Columns = Sequence[tuple[str, bool]]


def markdown_table(columns: Columns, rows: Sequence[Sequence[str]]) -> str:
    """A Markdown table of ``rows`` (text cells) under ``columns``, right-aligned where a column says so."""
    head = "| " + " | ".join(name for name, _ in columns) + " |"
    rule = "|" + "|".join("---:" if right else "---" for _, right in columns) + "|"
    body = ["| " + " | ".join(row) + " |" for row in rows]
    return "\n".join([head, rule, *body]) + "\n"


#: The table's columns (header, right-aligned).
WORLD_COLUMNS = (
    ("world", False),
    ("seed", True),
    ("odometry", False),
    ("drive", False),
    ("scans", True),
    ("mean cm", True),
    ("p95 cm", True),
    ("complete %", True),
    ("spurious %", True),
    ("walls / seen", True),
    ("ATE m", True),
    ("odometry ATE m", True),
    ("scans/s", True),
)


def _f(value: float, scale: float = 1.0, digits: int = 1) -> str:
    return "n/a" if not math.isfinite(value) else f"{value * scale:.{digits}f}"


def worlds_rows(results: Sequence[WorldResult]) -> list[list[str]]:
    """The table's rows as text: one per case, then the summary row (means; walls as the mean ratio)."""
    rows = [
        [
            r.kind,
            str(r.seed),
            r.odometry,
            r.drive,
            f"{r.scans:,}",
            _f(r.mean_error_m, 100, 2),
            _f(r.p95_error_m, 100, 2),
            _f(r.completeness, 100),
            _f(r.spurious_share, 100),
            f"{r.walls_mapped} / {r.walls_seen}",
            _f(r.ate_m, 1, 3),
            _f(r.odometry_ate_m, 1, 3),
            f"{r.scans_per_s:,.0f}",
        ]
        for r in results
    ]
    s = summarize(results)
    if results:
        rows.append(
            [
                f"summary ({s['cases']} cases, {s['cases_meeting_targets']} on target)",
                "",
                "",
                "",
                f"{s['scans']:,}",
                _f(s["mean_error_m"], 100, 2),
                _f(s["p95_error_m"], 100, 2),
                _f(s["completeness"], 100),
                _f(s["spurious_share"], 100),
                f"{_f(s['wall_ratio'], 1, 2)}x",
                _f(s["ate_m"], 1, 3),
                _f(s["odometry_ate_m"], 1, 3),
                f"{s['scans_per_s']:,.0f}",
            ]
        )
    return rows


def worlds_markdown(results: Sequence[WorldResult]) -> str:
    """The suite's figures as a Markdown table."""
    return markdown_table(WORLD_COLUMNS, worlds_rows(results))
