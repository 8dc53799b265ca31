"""What the agent's step spends on recording the pose graph (robot_agent.mapping.MappingLoop._with_graph)
as the graph grows: a stand-in graph of ``--keyframes`` keyframes, one of them moved a step, no closures;
prints the median over ``--steps`` steps (ms). Run it with ``PYTHONPATH`` at an older tree for the
baseline in the same session (the stand-in answers both the older ``keyframe_rows`` and the newer
``keyframe_array``):

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

    def keyframe_array(self) -> FloatArray:
        return self.rows.copy()

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


def _median_ms(n: int, steps: int) -> float:
    rng = np.random.default_rng(0)
    graph = _Graph(n, rng)
    loop = SimpleNamespace(
        _keyframe_offset=0, _sent_keyframes=np.full((0, 3), np.nan), _prev_closures=0, _prev_keyframes={}
    )
    times = []
    for step in range(steps):
        graph.rows[rng.integers(n), 2] += 0.01  # a keyframe moved
        rec = StepRecord(step, 1e9, step, [], [], [1e9, 0.0, 0.0, 0.0], [])
        t0 = time.perf_counter()
        MappingLoop._with_graph(loop, rec, graph)  # type: ignore[arg-type]
        times.append(time.perf_counter() - t0)
    return statistics.median(times[steps // 5 :]) * 1e3  # the first step records every keyframe


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--keyframes", type=int, nargs="+", default=[1000, 10000, 70000])
    parser.add_argument("--steps", type=int, default=60)
    args = parser.parse_args()
    for n in args.keyframes:
        print(f"{n:>7} keyframes: median {_median_ms(n, args.steps):9.3f} ms a step")


if __name__ == "__main__":
    main()
