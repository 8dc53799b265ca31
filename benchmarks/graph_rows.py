"""What the agent's step spends on recording the pose graph (robot_agent.mapping.MappingLoop._with_graph)
as the graph grows: a stand-in graph of ``--keyframes`` keyframes whose estimate an optimisation changes
(one keyframe moved) every ``--moved-every`` steps (10: a keyframe every 0.5 m at 0.5 m/s, an iSAM2
update each), no closures; prints the median and the mean over ``--steps`` steps (ms). Run it with
``PYTHONPATH`` at an older tree for the baseline in the same session (the stand-in answers the older
``keyframe_rows`` and ``keyframe_array`` and the newer ``keyframe_changes``):

    .venv/bin/python benchmarks/graph_rows.py --keyframes 1000 10000 70000
    PYTHONPATH=<older tree> .venv/bin/python benchmarks/graph_rows.py --keyframes 1000 10000 70000
"""

from __future__ import annotations

import argparse
import statistics
import time
from types import SimpleNamespace

import numpy as np

from robot_agent.mapping import MappingLoop
from robot_agent.store import StepRecord
from shared.types import FloatArray, Pose2D

__all__ = ["main"]


class _Graph:
    """A pose graph's reading side with ``n`` keyframes (as the online mapper answers it)."""

    def __init__(self, n: int, rng: np.random.Generator) -> None:
        self.rows = np.column_stack([np.arange(n), np.arange(n) * 0.1, rng.random((n, 3))])
        self.estimate = object()

    def keyframe_array(self) -> FloatArray:
        return self.rows.copy()

    def keyframe_changes(self, seen: object | None, since: int) -> tuple[object, int, FloatArray]:
        first = since if seen is self.estimate else 0
        return self.estimate, first, self.rows[first:].copy()

    def keyframe_rows(self) -> list[list[float]]:  # as the mapper built them before: a Pose2D each
        out = []
        for k, stamp, x, y, th in self.rows.tolist():
            p = Pose2D(x, y, th)
            out.append([k, stamp, p.x_m, p.y_m, p.theta_rad])
        return out

    def closure_pairs(self, since: int = 0) -> list[list[int]]:
        return []

    def pose_covariance(self) -> None:
        return None


def _step_ms(n: int, steps: int, moved_every: int) -> tuple[float, float]:
    rng = np.random.default_rng(0)
    graph = _Graph(n, rng)
    loop = SimpleNamespace(
        _keyframe_offset=0,
        _sent_keyframes=np.full((0, 3), np.nan),
        _prev_closures=0,
        _prev_keyframes={},
        _seen_estimate=None,
        _compare_from=0,
    )
    times = []
    for step in range(steps):
        if step % moved_every == 0:
            graph.rows[rng.integers(n), 2] += 0.01  # an optimisation moved a keyframe
            graph.estimate = object()
        rec = StepRecord(step, 1e9, step, [], [], [1e9, 0.0, 0.0, 0.0], [])
        t0 = time.perf_counter()
        MappingLoop._with_graph(loop, rec, graph)  # type: ignore[arg-type]
        times.append(time.perf_counter() - t0)
    kept = times[steps // 5 :]  # the first step records every keyframe
    return statistics.median(kept) * 1e3, statistics.fmean(kept) * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--keyframes", type=int, nargs="+", default=[1000, 10000, 70000])
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--moved-every", type=int, default=10, help="steps between two optimisations [10]")
    args = parser.parse_args()
    for n in args.keyframes:
        median, mean = _step_ms(n, args.steps, args.moved_every)
        print(f"{n:>7} keyframes: median {median:9.3f} ms a step, mean {mean:9.3f} ms")


if __name__ == "__main__":
    main()
