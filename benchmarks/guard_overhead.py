"""What the guarded path costs a downloaded kernel per call: the kernel runs in a confined worker process
(robot_agent/kernels/proc.py, docs/reliability/sandbox.md), each call crosses a socket with a deadline, and
the guard checks the result (robot_agent/guard.py). Built-in kernels run in-process, unguarded.

    .venv/bin/python benchmarks/guard_overhead.py [--calls 2000]

Runs DBSCAN on the noise-removal inputs of a simulated drive (the segmented points of real-size URG-04LX
scans, several hundred points each), the same inputs in the same order, three ways interleaved call by
call (so the shared machine's drift hits all three alike): the kernel in-process (the baseline: how a
built-in runs), the kernel in-process with the guard's result check, and the agent's path for a
downloaded kernel (guarded, in its worker process). Prints the median and p99 per call and the median
overhead over the baseline, all measured in this run.
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any

import numpy as np

from robot_agent.guard import guarded
from robot_agent.kernels.dryrun import load_in_worker
from shared.kernels import REGISTRY
from shared.kernels.conformance import check_result
from shared.kernels.noise.dbscan import Dbscan
from shared.sim import default_world, simulate_run


class DownloadedDbscan(Dbscan):
    """DBSCAN under another version (stands in for a downloaded, verified kernel)."""

    version = "1.9.0"


#: The same kernel as the source a robot downloads.
SOURCE = b"""
from shared.kernels.noise.dbscan import Dbscan


class DownloadedDbscan(Dbscan):
    version = "1.9.0"
"""


def _inputs(n: int) -> list[np.ndarray]:
    seg = REGISTRY.create("segmentation", "abd-iepf")
    out: list[np.ndarray] = []
    for scan in simulate_run(default_world(), seed=0).scans[:n]:
        out.append(np.asarray(seg.apply(scan).points))  # type: ignore[attr-defined]
    return out


def _p(values: list[float], q: float) -> float:
    return sorted(values)[min(len(values) - 1, int(q * len(values)))]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--calls", type=int, default=2000, help="calls of each variant [2000]")
    args = p.parse_args(argv)
    inputs = _inputs(min(args.calls, 400))
    fallback = Dbscan()

    class ChecksOnly(DownloadedDbscan):  # the guard's result check, in-process
        def apply(self, points: Any) -> Any:
            out = super().apply(points)
            check_result(self.stage, out, len(points))
            return out

    remote: Any = load_in_worker(
        SOURCE, "noise-removal", "dbscan", "1.9.0", memory_mb=256.0, call_s=5.0, import_s=30.0
    )
    variants: dict[str, Any] = {
        "kernel alone (baseline)": DownloadedDbscan(),
        "result check only, in-process": ChecksOnly(),
        "guarded, in its worker process": guarded(remote, lambda: fallback, lambda c, why: None, 1e9)(),
    }
    times: dict[str, list[float]] = {k: [] for k in variants}
    for i in range(args.calls):
        points = inputs[i % len(inputs)]
        for name, kernel in variants.items():
            t0 = time.perf_counter()
            kernel.apply(points)
            times[name].append((time.perf_counter() - t0) * 1e3)
    remote.worker.close()
    base = statistics.median(times["kernel alone (baseline)"])
    sizes = sorted(len(p) for p in inputs)
    print(
        f"{args.calls} calls each, {len(inputs)} distinct inputs (simulated drive, median"
        f" {sizes[len(sizes) // 2]} points), interleaved"
    )
    print(f"{'variant':40s} {'median ms':>10s} {'p99 ms':>8s} {'overhead':>10s}")
    for name, ts in times.items():
        med = statistics.median(ts)
        print(f"{name:40s} {med:10.3f} {_p(ts, 0.99):8.3f} {(med - base) * 1e3:8.1f} us")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
