"""The report's figures as PNG files (matplotlib, Agg backend: no display needed)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from shared.bench.table3 import PAPER_TABLE3, Table3Row
from shared.report.experiments import AccuracyRow, TimingRun
from shared.report.suite import ERROR_BANDS_M, SuiteRun, segment_errors_m
from shared.types import FloatArray

__all__ = ["plot_area_sweep", "plot_maps", "plot_suite_grid", "plot_timing"]

COLOURS = {"linemap": "#1f77b4", "ekf-slam": "#d62728", "kmeans": "#1f77b4", "fcm": "#2ca02c"}


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_area_sweep(rows: list[Table3Row], path: Path) -> Path:
    """Fig. 19: area error (%) against cluster count for k-means and FCM (mean and spread over seeds and
    line methods), with the paper's Table 3 values (mean over its line methods) beside them."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4.2), dpi=120)
    for clustering, label in (("kmeans", "k-means"), ("fcm", "FCM")):
        counts = sorted({r.clusters for r in rows if r.clustering == clustering})
        means, lows, highs = [], [], []
        for k in counts:
            vals = [r.area_error_pct for r in rows if r.clustering == clustering and r.clusters == k]
            got = np.array([v for v in vals if v is not None], dtype=float)
            means.append(got.mean() if got.size else np.nan)
            lows.append(got.min() if got.size else np.nan)
            highs.append(got.max() if got.size else np.nan)
        c = COLOURS[clustering]
        ax.plot(counts, means, "o-", color=c, label=f"linemap, {label} (mean; band: min-max)")
        ax.fill_between(counts, lows, highs, color=c, alpha=0.15)
        paper = sorted({k for (cl, _l, k) in PAPER_TABLE3 if cl == clustering})
        pv = [
            np.mean([v for (cl, _l, kk), v in PAPER_TABLE3.items() if cl == clustering and kk == k])
            for k in paper
        ]
        ax.plot(paper, pv, "s--", color=c, mfc="white", label=f"paper Table 3, {label} (mean of CJ/HT/SVD)")
    ax.set_xlabel("clusters")
    ax.set_ylabel("area error (%)")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("Area error against cluster count (Fig. 19)")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def _rolling_median(x: FloatArray, window: int) -> FloatArray:
    if len(x) < window:
        return x
    from numpy.lib.stride_tricks import sliding_window_view

    core = np.median(sliding_window_view(x, window), axis=1)
    return np.concatenate([np.full(window - 1, np.nan), core])


def plot_timing(runs: list[TimingRun], path: Path) -> Path:
    """Fig. 24: time per step against step number, linemap and the EKF on the same scans (rolling median
    over 25 steps; raw steps faint); the EKF's landmark count on the right axis."""
    plt = _plt()
    cols = min(len(runs), 3)
    rows = -(-len(runs) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(6.2 * cols, 4.2 * rows), dpi=110, squeeze=False)
    for ax, run in zip(axes.flat, runs, strict=False):
        for mapped in (run.linemap, run.ekf):
            c = COLOURS[mapped.method]
            steps = np.arange(1, len(mapped.step_ms) + 1)
            ax.plot(steps, mapped.step_ms, color=c, alpha=0.15, lw=0.5)
            ax.plot(
                steps,
                _rolling_median(mapped.step_ms, 25),
                color=c,
                lw=1.6,
                label=f"{mapped.method} (median of 25)",
            )
        ax.set_yscale("log")
        ax.set_xlabel("step")
        ax.set_ylabel("time per step (ms, log scale)")
        ax.grid(alpha=0.3, which="both")
        ax.set_title(f"{run.source}, {run.steps:,} steps")
        if run.ekf.landmarks is not None:
            twin = ax.twinx()
            twin.plot(np.arange(1, len(run.ekf.landmarks) + 1), run.ekf.landmarks, color="grey", ls=":", lw=1)
            twin.set_ylabel("EKF landmarks (dotted)", color="grey")
        ax.legend(fontsize=8, loc="upper left")
    fig.suptitle("Time per step: linemap against line-segment EKF-SLAM (Fig. 24)")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def plot_maps(rows: list[AccuracyRow], walls: FloatArray, world: str, seed: int, path: Path) -> Path:
    """The maps of both methods on one simulated world and seed, true walls in grey underneath."""
    plt = _plt()
    pick = [r for r in rows if r.world == world and r.seed == seed]
    fig, axes = plt.subplots(1, len(pick), figsize=(6.4 * len(pick), 5.6), dpi=120, squeeze=False)
    for ax, row in zip(axes[0], pick, strict=True):
        for x0, y0, x1, y1 in walls:
            ax.plot([x0, x1], [y0, y1], color="#bbbbbb", lw=3, solid_capstyle="butt")
        for x0, y0, x1, y1 in row.run.segments:
            ax.plot([x0, x1], [y0, y1], color=COLOURS[row.method], lw=1.2)
        ax.plot(row.run.poses[:, 0], row.run.poses[:, 1], color="#ff7f0e", lw=0.6, alpha=0.8)
        acc = row.accuracy
        ax.set_title(
            f"{row.method}: {acc.n_segments} segments, completeness {acc.completeness:.0%}, "
            f"spurious {acc.spurious_share:.1%}",
            fontsize=9,
        )
        ax.set_aspect("equal")
        ax.grid(alpha=0.2)
    fig.suptitle(f"{world} world, seed {seed}: map (colour) over the true walls (grey), trajectory (orange)")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def plot_suite_grid(run: SuiteRun, path: Path, cols: int = 4) -> Path:
    """One small map per kind of the scenario suite (its first seed): true walls grey, mapped walls
    coloured by their mean distance to the truth (blue / orange / red, :data:`ERROR_BANDS_M`), the
    pipeline's trajectory green; each titled with its mean error, completeness and walls / seen."""
    plt = _plt()
    kinds = list(run.maps)
    figures = {(r.kind, r.seed): r for r in run.results}
    n_cols = max(1, min(cols, len(kinds)))
    n_rows = max(1, -(-len(kinds) // n_cols))
    fig, axes = plt.subplots(n_rows, n_cols, figsize=(4.2 * n_cols, 3.4 * n_rows), dpi=100, squeeze=False)
    for ax in axes.flat[len(kinds) :]:
        ax.axis("off")
    bands = ("#1f77b4", "#ff7f0e", "#d62728")
    for ax, kind in zip(axes.flat, kinds, strict=False):
        m = run.maps[kind]
        for x0, y0, x1, y1 in m.truth:
            ax.plot([x0, x1], [y0, y1], color="#bbbbbb", lw=3.5, solid_capstyle="butt")
        errors = segment_errors_m(m.segments, m.truth)
        band = np.searchsorted(np.asarray(ERROR_BANDS_M), errors)
        for (x0, y0, x1, y1), b in zip(m.segments, band, strict=True):
            ax.plot([x0, x1], [y0, y1], color=bands[int(b)], lw=1.1)
        if len(m.trajectory):
            ax.plot(m.trajectory[:, 1], m.trajectory[:, 2], color="#2ca02c", lw=0.6, alpha=0.8)
        r = figures.get((kind, run.seeds[0]))
        sub = ""
        if r is not None:
            complete = f"{r.completeness:.0%}" if np.isfinite(r.completeness) else "n/a"
            sub = f"{r.mean_error_m * 100:.1f} cm, {complete} complete, {r.walls_mapped}/{r.walls_seen} walls"
        ax.set_title(f"{kind}\n{sub}", fontsize=8)
        ax.set_aspect("equal")
        ax.tick_params(labelsize=6)
        ax.grid(alpha=0.2)
    fig.suptitle(
        f"Scenario suite, seed {run.seeds[0]}: true walls grey; mapped walls blue (<= 5 cm), orange "
        "(<= 10 cm), red (spurious); trajectory green",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path
