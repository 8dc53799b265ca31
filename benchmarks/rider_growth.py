"""The pose graph alone driven round the same place for many laps: with riders (each node, once the lap
after it passes its place, rides on the newer node there: shared.slam.riders) and without (every node
stays in the solver). Every ``--every`` laps it prints the nodes in the solver, the edges, and the
median and largest update time (ms) over the laps since the row before; a rebuild from scratch (every
``RESOLVE_EVERY_UPDATES`` updates) is among them.

A circle of ``--per-lap`` nodes (0.5 m apart, as keyframes), motions that turn 0.3 degrees too far, and
from the second lap on a loop edge from each node to the node at its place one lap back, as the robot's
loop closure adds them. This is the solver's share of a day's patrol, not the scan matching's.

    .venv/bin/python benchmarks/rider_growth.py [--laps 200] [--per-lap 100] [--every 20] [--no-riders]
"""

from __future__ import annotations

import argparse
import math
import statistics
import time

import numpy as np

from shared.slam import PoseGraph
from shared.types import Pose2D

__all__ = ["main"]

SEQ = np.diag([1.0 / 0.02**2, 1.0 / 0.02**2, 1.0 / 0.01**2])
LOOP = np.diag([1.0 / 0.01**2, 1.0 / 0.01**2, 1.0 / 0.005**2])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--laps", type=int, default=200)
    parser.add_argument("--per-lap", type=int, default=100, help="nodes a lap (0.5 m apart)")
    parser.add_argument("--every", type=int, default=20, help="laps between two rows")
    parser.add_argument("--no-riders", action="store_true", help="every node stays in the solver")
    args = parser.parse_args()
    n_lap = args.per_lap
    radius = 0.5 * n_lap / (2 * math.pi)

    def truth(k: int) -> Pose2D:
        a = 2 * math.pi * (k % n_lap) / n_lap
        return Pose2D(radius * math.cos(a), radius * math.sin(a), a + math.pi / 2)

    graph = PoseGraph()
    graph.add_node(truth(0))
    graph.update()
    times: list[float] = []
    print(f"{'lap':>6} {'nodes':>8} {'solved':>8} {'edges':>8} {'p50_ms':>8} {'max_ms':>8} {'err_cm':>8}")
    for k in range(1, args.laps * n_lap + 1):
        m = truth(k - 1).between(truth(k))
        measured = Pose2D(m.x_m, m.y_m, m.theta_rad + math.radians(0.3))
        graph.add_node(graph.pose(k - 1) @ measured)
        graph.add_edge(k - 1, k, measured, SEQ, loop=False)
        if k >= n_lap:
            graph.add_edge(k - n_lap, k, truth(k - n_lap).between(truth(k)), LOOP, loop=True)
            if not args.no_riders:
                graph.ride(k - n_lap, k)
        t0 = time.perf_counter()
        graph.update()
        times.append((time.perf_counter() - t0) * 1e3)
        if k % (args.every * n_lap) == 0:
            p, t = graph.pose(k), truth(k)
            print(
                f"{k // n_lap:>6} {len(graph):>8} {graph.solved_nodes:>8} {len(graph.edges):>8} "
                f"{statistics.median(times):>8.2f} {max(times):>8.1f} "
                f"{100 * math.hypot(p.x_m - t.x_m, p.y_m - t.y_m):>8.2f}",
                flush=True,
            )
            times = []


if __name__ == "__main__":
    main()
