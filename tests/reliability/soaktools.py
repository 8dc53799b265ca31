"""The load soak's figures and verdict (docs/reliability.md; docs/reliability/soak.md).

``benchmarks/server_load.py`` (:func:`benchmarks.server_load.measure`) loads one real ``linemap server``
process from this one; here its raw results become the soak's figures: server RSS (sampled from
``/proc/PID/status`` every few seconds) and upload latency per quarter of the run, and the verdict.

The verdict (:meth:`SoakFigures.problems`, empty when the run passed):

- **errors**: none of any kind (upload, long-poll, message, SSE: non-2xx or exception).
- **memory, no growth trend**: the Theil–Sen slope (median of the pairwise slopes) of RSS over the
  *second half* of the run, times that half's length, at most ``MEM_GROWTH_FRACTION`` of that half's median
  RSS (and never less than ``MEM_GROWTH_FLOOR_KB``). Why this form: the first half is warm-up (allocator
  arenas, SQLite page caches, SQLAlchemy's statement cache fill up and then stay); CPython's RSS in steady
  state is a step function with spikes (arenas, requests in flight), and least squares is dragged by a
  single spike near either end of the window, while Theil–Sen ignores up to 29 % outliers and still
  measures a real leak's steady slope exactly. Sensitivity: at 200 uploads/s over a 300 s second half and
  a ~230 MB server, 5 % is ~200 bytes kept per upload (one small dict), against the ~10 kB body a leaking
  handler would keep.
  The least-squares slope and the quarter medians are reported beside it.
- **latency, no growth trend**: the last quarter's p50 upload latency at most ``LATENCY_FACTOR`` times the
  second quarter's (or the second quarter's plus ``LATENCY_FLOOR_S``, whichever is larger: a p50 of a few
  ms moves by a ms when the shared machine is busy). A per-upload cost that grows with the stored
  history (versions, trajectory) would double it long before 10 minutes.
- **enough data**: uploads in every quarter and at least 3 RSS samples in the second half (a run that
  measured nothing cannot pass).
"""

from __future__ import annotations

import json
import math
import os
import statistics
from bisect import bisect_left
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from benchmarks.server_load import Config, Results, nearest_rank

__all__ = [
    "ARTIFACTS",
    "LATENCY_FACTOR",
    "LATENCY_FLOOR_S",
    "MEM_GROWTH_FLOOR_KB",
    "MEM_GROWTH_FRACTION",
    "SECONDS_ENV",
    "Quarter",
    "SoakFigures",
    "analyse",
    "least_squares_slope",
    "load_average",
    "sample_period_s",
    "soak_seconds",
    "theil_sen_slope",
    "write_artifacts",
]

ROOT = Path(__file__).resolve().parents[2]
ARTIFACTS = Path(os.environ.get("LINEMAP_TEST_ARTIFACTS", ROOT / "test-artifacts")) / "reliability"
SECONDS_ENV = "LINEMAP_SOAK_SECONDS"
MEM_GROWTH_FRACTION = 0.05
MEM_GROWTH_FLOOR_KB = 4096
LATENCY_FACTOR = 2.0
LATENCY_FLOOR_S = 0.005


def soak_seconds(default_s: float = 600.0) -> float:
    """The soak's length from ``$LINEMAP_SOAK_SECONDS`` (seconds), else ``default_s``."""
    raw = os.environ.get(SECONDS_ENV, "").strip()
    if not raw:
        return default_s
    try:
        value = float(raw)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value >= 8):
        raise ValueError(f"{SECONDS_ENV}={raw!r}: expected a number of seconds, at least 8 (e.g. 600)")
    return value


def sample_period_s(duration_s: float) -> float:
    """RSS sample period: about 40 samples a run, between 1 and 5 s (600 s: every 5 s)."""
    return min(5.0, max(1.0, duration_s / 40))


def least_squares_slope(t: Sequence[float], y: Sequence[float]) -> float:
    """Ordinary least-squares slope of ``y`` over ``t`` (units of y per unit of t; 0 for < 2 points). O(n)."""
    if len(t) < 2:
        return 0.0
    mt, my = statistics.fmean(t), statistics.fmean(y)
    var = sum((a - mt) ** 2 for a in t)
    return sum((a - mt) * (b - my) for a, b in zip(t, y, strict=True)) / var if var else 0.0


def theil_sen_slope(t: Sequence[float], y: Sequence[float]) -> float:
    """Theil–Sen slope: the median of the slopes of all pairs of points with distinct ``t`` (0 for none).
    Breakdown point 29 %: that share of arbitrary outliers cannot move it far. O(n² log n), n ~ 60 here."""
    slopes = [
        (y[j] - y[i]) / (t[j] - t[i]) for i in range(len(t)) for j in range(i + 1, len(t)) if t[j] != t[i]
    ]
    return statistics.median(slopes) if slopes else 0.0


@dataclass(frozen=True, slots=True)
class Quarter:
    """One quarter of the run: uploads sent in it, their latency percentiles (ms), median RSS (MB)."""

    index: int
    uploads: int
    p50_ms: float | None
    p95_ms: float | None
    p99_ms: float | None
    rss_median_mb: float | None


@dataclass(frozen=True, slots=True)
class SoakFigures:
    """Everything the soak measured (MB = 2**20 bytes); :meth:`problems` is the verdict."""

    duration_s: float
    robots: int
    period_s: float
    elapsed_s: float
    uploads: int
    uploads_per_s: float
    errors: int
    errors_by_kind: dict[str, int]
    skipped_slots: int
    skipped_messages: int
    rss_samples: int
    rss_start_mb: float | None
    rss_end_mb: float | None
    rss_peak_mb: float
    rss_slope_ls_mb_per_min: float  # second half, least squares
    rss_slope_ts_mb_per_min: float  # second half, Theil–Sen (the asserted one)
    rss_trend_growth_mb: float  # Theil–Sen slope x second half's length
    rss_growth_bound_mb: float
    rss_q4_vs_q2_pct: float | None  # last quarter's median RSS against the second's
    latency_q4_p50_bound_ms: float | None
    quarters: tuple[Quarter, ...]
    series: tuple[tuple[float, float, int, float | None], ...]  # (t_s, rss_mb, uploads since, their p50_ms)
    load_avg: tuple[float, float] | None = None  # the machine's 1-min load average before and after

    def problems(self, trends: bool = True) -> list[str]:
        """Why the run fails (empty: it passed). ``trends=False``: errors and empty quarters only (a short
        run on a shared machine tells no trend: that is the soak's verdict)."""
        out: list[str] = []
        if self.errors:
            out.append(f"{self.errors} errors, by kind {self.errors_by_kind} (expected 0)")
        if empty := [q.index for q in self.quarters if not q.uploads]:
            out.append(f"no upload answered in quarter(s) {empty}")
        if not trends:
            return out
        if sum(1 for t, *_ in self.series if t >= self.duration_s / 2) < 3:
            out.append(f"only {self.rss_samples} RSS samples, fewer than 3 in the second half")
        elif self.rss_trend_growth_mb > self.rss_growth_bound_mb:
            out.append(
                f"server RSS grows: trend {self.rss_trend_growth_mb:.2f} MB over the second half "
                f"({self.rss_slope_ts_mb_per_min:.3f} MB/min), above the bound "
                f"{self.rss_growth_bound_mb:.2f} MB"
            )
        q2, q4 = self.quarters[1].p50_ms, self.quarters[3].p50_ms
        bound = self.latency_q4_p50_bound_ms
        if q2 is not None and q4 is not None and bound is not None and q4 > bound:
            out.append(
                f"upload latency grows: last quarter p50 {q4} ms > {bound} ms (second quarter: {q2} ms)"
            )
        return out

    def to_json(self) -> dict[str, Any]:
        return asdict(self) | {"problems": self.problems()}

    def to_markdown(self, title: str) -> str:
        def fmt(x: object) -> str:
            return "-" if x is None else str(x)

        lines = [
            f"## {title}",
            "",
            f"{self.robots} robots x 1 upload / {self.period_s:g} s, {self.duration_s:g} s of load "
            f"({self.elapsed_s:.1f} s measured), one server process (SQLite), load from a second process"
            + (
                "."
                if self.load_avg is None
                else f"; machine load average {self.load_avg[0]} before, {self.load_avg[1]} after (2 cores)."
            ),
            "",
            "| figure | value |",
            "|---|---:|",
            f"| uploads (answered) | {self.uploads} |",
            f"| uploads/s | {self.uploads_per_s} |",
            f"| errors | {self.errors} |",
            f"| upload slots skipped (client > 1 period behind) | {self.skipped_slots} |",
            f"| control messages not sent (client past the end) | {self.skipped_messages} |",
            f"| server RSS first / last / peak sample (MB) | {fmt(self.rss_start_mb)} / "
            f"{fmt(self.rss_end_mb)} / {self.rss_peak_mb} |",
            f"| RSS slope, 2nd half, Theil–Sen / least squares (MB/min) | {self.rss_slope_ts_mb_per_min} / "
            f"{self.rss_slope_ls_mb_per_min} |",
            f"| RSS trend over the 2nd half / bound (MB) | {self.rss_trend_growth_mb} / "
            f"{self.rss_growth_bound_mb} |",
            f"| RSS median, last quarter vs second (%) | {fmt(self.rss_q4_vs_q2_pct)} |",
            f"| last-quarter p50 bound (ms) | {fmt(self.latency_q4_p50_bound_ms)} |",
            f"| RSS samples | {self.rss_samples} |",
            "",
            "| quarter | uploads | p50 (ms) | p95 (ms) | p99 (ms) | RSS median (MB) |",
            "|---|---:|---:|---:|---:|---:|",
            *(
                f"| Q{q.index} | {q.uploads} | {fmt(q.p50_ms)} | {fmt(q.p95_ms)} | {fmt(q.p99_ms)} | "
                f"{fmt(q.rss_median_mb)} |"
                for q in self.quarters
            ),
            "",
            f"verdict: {'; '.join(self.problems()) or 'pass (0 errors, no growth in memory or latency)'}",
        ]
        return "\n".join(lines) + "\n"


def _ms(xs: list[float], q: float) -> float | None:
    value = nearest_rank(xs, q)
    return None if value is None else round(1000 * value, 2)


def _mb(kb: float) -> float:
    return round(kb / 1024, 2)


def load_average() -> float:
    """The machine's 1-minute load average (``/proc/loadavg``)."""
    return float(Path("/proc/loadavg").read_text().split()[0])


def analyse(cfg: Config, res: Results, load_avg: tuple[float, float] | None = None) -> SoakFigures:
    """The soak's figures from one :func:`~benchmarks.server_load.measure` run (``load_avg``: the machine's
    load before and after, for the record). O(n log n) in uploads."""
    dur = cfg.duration_s
    ups = sorted(zip(res.upload_at_s, res.upload_s, strict=True))
    up_t = [t for t, _ in ups]
    samples = sorted(res.rss_samples)
    quarters: list[Quarter] = []
    for k in range(4):
        lo, hi = k * dur / 4, (k + 1) * dur / 4 if k < 3 else math.inf
        lat = [s for t, s in ups if lo <= t < hi]
        rss = [kb for t, kb in samples if lo <= t < hi]
        med = _mb(statistics.median(rss)) if rss else None
        quarters.append(Quarter(k + 1, len(lat), _ms(lat, 50), _ms(lat, 95), _ms(lat, 99), med))
    half = [(t, kb) for t, kb in samples if t >= dur / 2]
    ht, hy = [t for t, _ in half], [float(kb) for _, kb in half]
    ts, ls = theil_sen_slope(ht, hy), least_squares_slope(ht, hy)  # kB/s
    span = ht[-1] - ht[0] if len(ht) > 1 else 0.0
    bound_kb = max(MEM_GROWTH_FLOOR_KB, MEM_GROWTH_FRACTION * statistics.median(hy)) if hy else 0.0
    q2, q4 = quarters[1], quarters[3]
    pct = None
    if q2.rss_median_mb and q4.rss_median_mb is not None:
        pct = round(100 * (q4.rss_median_mb / q2.rss_median_mb - 1), 2)
    lat_bound = None
    if q2.p50_ms is not None:
        lat_bound = round(max(LATENCY_FACTOR * q2.p50_ms, q2.p50_ms + 1000 * LATENCY_FLOOR_S), 2)
    series: list[tuple[float, float, int, float | None]] = []
    prev = 0.0
    for t, kb in samples:
        window = [s for _, s in ups[bisect_left(up_t, prev) : bisect_left(up_t, t)]]
        series.append((round(t, 2), _mb(kb), len(window), _ms(window, 50)))
        prev = t
    elapsed = res.elapsed_s or math.nan
    return SoakFigures(
        duration_s=dur,
        robots=cfg.robots,
        period_s=cfg.period_s,
        elapsed_s=round(res.elapsed_s, 2),
        uploads=len(ups),
        uploads_per_s=round(len(ups) / elapsed, 1),
        errors=sum(res.errors.values()),
        errors_by_kind=dict(res.errors),
        skipped_slots=res.skipped_slots,
        skipped_messages=res.skipped_messages,
        rss_samples=len(samples),
        rss_start_mb=_mb(samples[0][1]) if samples else None,
        rss_end_mb=_mb(samples[-1][1]) if samples else None,
        rss_peak_mb=_mb(max([kb for _, kb in samples] + [res.server_kb[1]])),
        rss_slope_ls_mb_per_min=round(ls * 60 / 1024, 3),
        rss_slope_ts_mb_per_min=round(ts * 60 / 1024, 3),
        rss_trend_growth_mb=_mb(ts * span),
        rss_growth_bound_mb=_mb(bound_kb),
        rss_q4_vs_q2_pct=pct,
        latency_q4_p50_bound_ms=lat_bound,
        quarters=tuple(quarters),
        series=tuple(series),
        load_avg=load_avg,
    )


def write_artifacts(fig: SoakFigures, name: str, title: str) -> tuple[Path, Path]:
    """``<name>.json`` and ``<name>.md`` under :data:`ARTIFACTS` (created); their paths."""
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    js, md = ARTIFACTS / f"{name}.json", ARTIFACTS / f"{name}.md"
    js.write_text(json.dumps(fig.to_json(), indent=2) + "\n")
    md.write_text(fig.to_markdown(title))
    return js, md
