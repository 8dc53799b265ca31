"""``linemap bench kernels``: time every kernel and one whole online step against library equivalents.

Data (a) is one simulated URG-04LX scan, data (b) an offline batch of 9 scans (N_smax = 9) with 52
clusters, both from :mod:`shared.bench.data`. Every figure is a median (and p99) of wall-clock time on one
core, with the library equivalent timed in the same run on the same data, so ratios survive a noisy machine.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np

from shared.bench import baselines as lib
from shared.bench.data import BenchData, batch_groups, make_bench_data
from shared.bench.timing import Timing, time_call
from shared.kernels import REGISTRY, Kernel, Stage
from shared.types import FloatArray, IntArray

__all__ = ["BenchReport", "Row", "run_kernel_bench"]

OFFLINE_CLUSTERS = 52


@dataclass(frozen=True, slots=True)
class Row:
    """One benchmark line: our kernel and (if any) its library equivalent, on the same data."""

    key: str
    data: str
    ours: Timing
    library: str | None = None
    baseline: Timing | None = None

    @property
    def ratio(self) -> float | None:
        """How many times faster ours is than the library (median over median)."""
        if self.baseline is None or self.ours.median_ms <= 0.0:
            return None
        return self.baseline.median_ms / self.ours.median_ms

    def as_dict(self) -> dict[str, Any]:
        """JSON-compatible figures."""
        out: dict[str, Any] = {"data": self.data, **self.ours.as_dict()}
        if self.baseline is not None:
            out["library"] = self.library
            out["baseline_median_ms"] = self.baseline.median_ms
            out["baseline_p99_ms"] = self.baseline.p99_ms
            out["ratio"] = self.ratio
        return out


@dataclass(slots=True)
class BenchReport:
    """All rows plus quality checks against the libraries."""

    rows: list[Row] = field(default_factory=list)
    quality: dict[str, dict[str, Any]] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)

    def row(self, key: str) -> Row:
        """The row named ``key``."""
        return next(r for r in self.rows if r.key == key)

    def as_dict(self) -> dict[str, Any]:
        """JSON: ``kernels`` rows by key, ``online_step``, ``offline_batch``, ``quality``, ``info``."""
        kernels = {r.key: r.as_dict() for r in self.rows if r.key not in ("online_step", "offline_batch")}
        out: dict[str, Any] = {"kernels": kernels, "quality": self.quality, "info": self.info}
        for key in ("online_step", "offline_batch"):
            if any(r.key == key for r in self.rows):
                out[key] = self.row(key).as_dict()
        return out


def _k(stage: Stage, name: str, **params: Any) -> Any:
    """A registered kernel (typed ``Any``: the benchmark drives every stage through its own ``apply``)."""
    return REGISTRY.create(stage, name, params)


@dataclass(slots=True)
class _Online:
    """The online-step chain: segmentation -> DBSCAN -> k-means -> hough-cluster, plus ICP."""

    segment: Any
    dbscan: Any
    kmeans: Any
    hough_cluster: Any
    icp: Any

    def run(self, data: BenchData) -> Any:
        seg = self.segment.apply(data.scan)
        noise = self.dbscan.apply(seg.points)
        groups = seg.labels[noise.keep]
        clusters = self.kmeans.apply(noise.points)
        lines = self.hough_cluster.apply(noise.points, groups)
        ref, _ = data.previous_scan.to_points()
        match = self.icp.apply(ref, seg.points, data.odometry_motion)
        return clusters, lines, match


def _library_online(data: BenchData, segment: Any, eps: float, minpts: int, k: int) -> Any:
    seg = segment.apply(data.scan)
    labels = lib.dbscan_sklearn(seg.points, eps, minpts)
    keep = labels >= 0
    pts, groups = seg.points[keep], seg.labels[keep]
    centres = lib.kmeans_sklearn(pts, k, n_init=10)
    lines = lib.hough_cluster_numpy(pts, groups)
    ref, _ = data.previous_scan.to_points()
    pose = lib.icp_ckdtree(ref, seg.points, data.odometry_motion)
    return centres, lines, pose


def run_kernel_bench(
    runs: int = 200,
    seed: int = 0,
    progress: Callable[[str], None] | None = None,
) -> BenchReport:
    """Run the whole benchmark; ``progress`` is called with a label before each measurement."""
    note = progress or (lambda _label: None)
    data = make_bench_data(seed)
    report = BenchReport()
    slow = max(3, runs // 50)

    def measure(
        key: str,
        label: str,
        ours: Callable[[], Any],
        library: str | None = None,
        base: Callable[[], Any] | None = None,
        lib_runs: int | None = None,
    ) -> None:
        note(key)
        mine = time_call(ours, runs=runs, budget_s=20.0)
        theirs = None
        if base is not None:
            theirs = time_call(base, runs=lib_runs or runs, warmup=1, budget_s=20.0)
        report.rows.append(Row(key, label, mine, library, theirs))

    # ---------------- (a) one scan ----------------
    scan_label = "a: 1 scan"
    segment = _k(Stage.SEGMENTATION, "abd-iepf")
    seg = segment.apply(data.scan)
    pts, labels = seg.points, seg.labels
    dbscan = _k(Stage.NOISE_REMOVAL, "dbscan")
    eps, minpts = dbscan.params.epsilon_m, dbscan.params.min_points
    kept = dbscan.apply(pts)
    clean, clean_groups = kept.points, labels[kept.keep]
    # Online mode clusters each step's new data into a few clusters (paper §3.3: one per step in online
    # mode; Listing 1 asks for cluster-no 2): the kernels' default n_clusters.
    kmeans = _k(Stage.CLUSTERING, "kmeans")
    k_online = int(kmeans.params.n_clusters)
    fcm = _k(Stage.CLUSTERING, "fcm", n_clusters=k_online)
    icp = _k(Stage.SCAN_MATCHING, "icp")
    ref, _ = data.previous_scan.to_points()
    report.info.update(
        scan_points=len(pts),
        scan_segments=seg.n_segments,
        online_clusters=k_online,
        batch_points=len(data.batch_points),
        batch_clusters=OFFLINE_CLUSTERS,
        dbscan=dict(epsilon_m=eps, min_points=minpts),
    )

    measure("segmentation/abd-iepf", scan_label, lambda: segment.apply(data.scan))
    measure(
        "noise-removal/dbscan",
        scan_label,
        lambda: dbscan.apply(pts),
        "sklearn DBSCAN",
        lambda: lib.dbscan_sklearn(pts, eps, minpts),
    )
    morph_baselines: dict[str, Callable[[FloatArray, float, tuple[int, int, int]], int]] = {
        "erosion": lib.erosion_ndimage,
        "dilation": lib.dilation_ndimage,
    }
    for name in ("erosion", "dilation", "opening"):
        morph = _k(Stage.NOISE_REMOVAL, name)
        reference = morph_baselines.get(name)
        base = (
            None if reference is None else partial(reference, pts, morph.params.cell_size_m, _psi_of(morph))
        )
        measure(
            f"noise-removal/{name}",
            scan_label,
            partial(morph.apply, pts),
            "scipy.ndimage" if base else None,
            base,
        )
    measure(
        "clustering/kmeans",
        f"{scan_label}, k={k_online}",
        lambda: kmeans.apply(clean),
        "sklearn KMeans n_init=10",
        lambda: lib.kmeans_sklearn(clean, k_online, n_init=10),
    )
    measure(
        "clustering/fcm",
        f"{scan_label}, c={k_online}",
        lambda: fcm.apply(clean),
        "skfuzzy cmeans",
        lambda: lib.cmeans_skfuzzy(clean, k_online),
        lib_runs=slow * 5,
    )
    hc = _k(Stage.STRAIGHT_LINE, "hough-cluster")
    measure(
        "straight-line/hough-cluster",
        scan_label,
        lambda: hc.apply(clean, clean_groups),
        "numpy Hough",
        lambda: lib.hough_cluster_numpy(clean, clean_groups),
    )
    measure(
        "scan-matching/icp",
        scan_label,
        lambda: icp.apply(ref, pts, data.odometry_motion),
        "cKDTree ICP",
        lambda: lib.icp_ckdtree(ref, pts, data.odometry_motion),
    )

    online = _Online(segment, dbscan, kmeans, hc, icp)
    measure(
        "online_step",
        scan_label,
        lambda: online.run(data),
        "sklearn/numpy/cKDTree chain",
        lambda: _library_online(data, segment, eps, minpts, k_online),
        lib_runs=max(20, runs // 4),
    )

    # ---------------- (b) offline batch of 9 scans ----------------
    batch_label = f"b: 9 scans, {OFFLINE_CLUSTERS} clusters"
    bpts = data.batch_points
    bgroups = batch_groups(data, [segment.apply(s).labels for s in data.batch_scans])
    bkeep = dbscan.apply(bpts)
    bclean = bkeep.points
    bkm = _k(Stage.CLUSTERING, "kmeans", n_clusters=OFFLINE_CLUSTERS)
    bfcm = _k(Stage.CLUSTERING, "fcm", n_clusters=OFFLINE_CLUSTERS)
    bclusters = bfcm.apply(bclean)
    svd = _k(Stage.STRAIGHT_LINE, "svd")
    hough = _k(Stage.STRAIGHT_LINE, "hough")

    measure(
        "noise-removal/dbscan (batch)",
        batch_label,
        lambda: dbscan.apply(bpts),
        "sklearn DBSCAN",
        lambda: lib.dbscan_sklearn(bpts, eps, minpts),
        lib_runs=slow * 5,
    )
    measure(
        "clustering/kmeans (batch)",
        batch_label,
        lambda: bkm.apply(bclean),
        "sklearn KMeans n_init=10",
        lambda: lib.kmeans_sklearn(bclean, OFFLINE_CLUSTERS, n_init=10),
        lib_runs=slow,
    )
    measure(
        "clustering/fcm (batch)",
        batch_label,
        lambda: bfcm.apply(bclean),
        "skfuzzy cmeans",
        lambda: lib.cmeans_skfuzzy(bclean, OFFLINE_CLUSTERS),
        lib_runs=3,
    )

    # Straight lines from the batch's 52 centroids, ordered along the scans and grouped by segment.
    border = _scan_order(bclusters.labels, bclusters.n_clusters)
    centroids = bclusters.centroids[border]
    cgroups = _centroid_groups(bclean, bgroups[bkeep.keep], bclusters.labels, len(border))[border]
    for name in ("centroid-join", "svd", "hough"):
        kern = _k(Stage.STRAIGHT_LINE, name)
        line_base: Callable[[], Any] | None = (
            partial(lib.svd_lines_numpy, centroids, cgroups) if name == "svd" else None
        )
        measure(
            f"straight-line/{name}",
            f"b: {len(centroids)} centroids",
            partial(kern.apply, centroids, cgroups),
            "numpy svd" if line_base else None,
            line_base,
        )

    def offline_ours() -> Any:
        keep = dbscan.apply(bpts)
        cl = bfcm.apply(keep.points)
        order = _scan_order(cl.labels, cl.n_clusters)
        g = _centroid_groups(keep.points, bgroups[keep.keep], cl.labels, cl.n_clusters)[order]
        return svd.apply(cl.centroids[order], g), hough.apply(cl.centroids[order], g)

    def offline_library() -> Any:
        labels = lib.dbscan_sklearn(bpts, eps, minpts)
        keep = labels >= 0
        centres, _ = lib.cmeans_skfuzzy(bpts[keep], OFFLINE_CLUSTERS)
        return lib.svd_lines_numpy(centres, np.zeros(len(centres), dtype=np.intp))

    measure(
        "offline_batch",
        f"{batch_label}: DBSCAN+FCM+SVD+Hough",
        offline_ours,
        "sklearn DBSCAN + skfuzzy + numpy svd",
        offline_library,
        lib_runs=3,
    )

    # ---------------- quality against the libraries ----------------
    note("quality")
    ref_labels = lib.dbscan_sklearn(bpts, eps, minpts)
    report.quality["dbscan_keep_identical_to_sklearn"] = {
        "value": bool(np.array_equal(bkeep.keep, ref_labels >= 0)),
        "target": True,
    }
    _, inertia = lib.kmeans_sklearn(bclean, OFFLINE_CLUSTERS, n_init=10)
    ours_q = bkm.apply(bclean).objective
    report.quality["kmeans_objective_vs_sklearn_best_of_10"] = {
        "value": ours_q / inertia - 1.0,
        "target": "<= +1 %",
    }
    _, fcm_ref = lib.cmeans_skfuzzy(bclean, OFFLINE_CLUSTERS)
    report.quality["fcm_objective_vs_skfuzzy"] = {
        "value": bclusters.objective / fcm_ref - 1.0,
        "target": "<= +1 %",
    }
    return report


def _psi_of(kernel: Kernel[Any]) -> tuple[int, int, int]:
    """The (psi_H, psi_V, psi_C) vector a morphology kernel uses."""
    fn = getattr(kernel, "psi", None)
    value = fn() if callable(fn) else fn
    if value is None:
        value = getattr(kernel.params, "psi", None)
    if value is None:
        return (1, 1, 0)
    a, b, c = value
    return int(a), int(b), int(c)


def _centroid_groups(points: FloatArray, groups: IntArray, labels: IntArray, k: int) -> IntArray:
    """Group of each centroid: the segment most of its points belong to (-1 if none)."""
    out = np.full(k, -1, dtype=np.intp)
    ok = (labels >= 0) & (groups >= 0)
    if not ok.any():
        return out
    counts = np.zeros((k, int(groups[ok].max()) + 1), dtype=np.int64)
    np.add.at(counts, (labels[ok], groups[ok]), 1)
    has = counts.sum(axis=1) > 0
    out[has] = counts[has].argmax(axis=1)
    return out


def _scan_order(labels: IntArray, k: int) -> IntArray:
    """Centroid indices sorted by the mean input index of their points (their position along the scan)."""
    ok = labels >= 0
    idx = np.flatnonzero(ok).astype(np.float64)
    sums = np.bincount(labels[ok], weights=idx, minlength=k)
    counts = np.bincount(labels[ok], minlength=k)
    mean = np.where(counts > 0, sums / np.maximum(counts, 1), np.inf)
    return np.argsort(mean, kind="stable")
