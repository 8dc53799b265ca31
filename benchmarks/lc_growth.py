"""How the robot's loop-closure state grows as it drives the same building again and again: a simulated
patrol of a suite world (default ``loop-block``, a corridor loop) for ``--laps`` laps through the agent's
own loop-closure mapper (:class:`robot_agent.mapping.PipelineSlot` with loop closure on: an
:class:`~shared.slam.OnlineGraphMapper` with its worker threads and the agent's bounded history; the map
is the same whatever the worker's timing). Every ``--every`` steps it prints the keyframes (all, and
those still holding their scan), the scans kept for redraws (all, and those still held), the closures,
the pose graph's nodes in the solver and its edges, the median and largest step time (ms) since the row
before,
the saved state's size and the time to take it and make its bytes, the last rebuild's time, and the
shown map against the world's walls (mean and 95th-percentile distance, walls, spurious share, the
share of the world's wall length mapped).

    .venv/bin/python benchmarks/lc_growth.py [--world loop-block] [--seed 0] [--laps 6] [--every 1000]
        [--no-places]

``--json FILE`` writes the rows too.
"""

from __future__ import annotations

import argparse
import json
import resource
import time
from pathlib import Path

import numpy as np

from robot_agent.mapping import PipelineSlot
from robot_agent.sources import laser_offset
from shared.metrics import line_accuracy
from shared.pipeline import PipelineConfig
from shared.protocol import MAX_TRAJECTORY_POSES
from shared.sim.patrol import scene_patrol
from shared.sim.worlds import build_scene
from shared.slam import OnlineGraphMapper

__all__ = ["main"]


def _row(  # type: ignore[no-untyped-def]
    online: OnlineGraphMapper, walls_true, step: int, t_run_s: float, step_ms: list[float], truth
) -> dict[str, float | int]:
    mapper = online._mapper
    graph = mapper.graph
    solved = getattr(graph, "solved_nodes", len(graph))  # nodes in the solver (riders are not)
    edges = len(graph._edges)
    times = sorted(step_ms) or [0.0]
    t0 = time.perf_counter()
    state = online.state()
    t1 = time.perf_counter()
    size = len(state.to_bytes())
    t2 = time.perf_counter()
    segments = online.snapshot().segments
    acc = line_accuracy(segments, walls_true)
    places = getattr(mapper, "places", None)  # None: code from before places were retired
    keys_retired = places.keyframes_retired if places is not None else 0
    scans_retired = places.scans_retired if places is not None else 0
    return {
        "step": step,
        "keyframes": len(mapper.keyframes),
        "keyframes_held": len(mapper.keyframes) - keys_retired,
        "kept_scans": len(mapper.stepped()),
        "kept_scans_held": len(mapper.stepped()) - scans_retired,
        "closures": online.closures,
        "graph_nodes": solved,
        "graph_edges": edges,
        "step_p50_ms": round(times[len(times) // 2], 2),
        "step_max_ms": round(times[-1], 1),
        "state_bytes": size,
        "state_take_ms": round((t1 - t0) * 1e3, 1),
        "state_bytes_ms": round((t2 - t1) * 1e3, 1),
        "last_rebuild_ms": round(online.redraw_ms[-1], 1) if online.redraw_ms else 0.0,
        "walls": len(segments),
        "mean_error_cm": round(acc.mean_distance_m * 100, 2),
        "p95_error_cm": round(acc.p95_distance_m * 100, 2),
        "spurious_pct": round(acc.spurious_share * 100, 1),
        "complete_pct": round(acc.completeness * 100, 1),  # of every wall of the world, seen or not
        **_keyframe_errors(mapper, truth),
        "rss_mb": round(_rss_mb(), 1),
        "run_s": round(t_run_s, 1),
    }


def _keyframe_errors(mapper, truth) -> dict[str, float]:  # type: ignore[no-untyped-def]
    """Position error (cm) of the graph's held keyframes (median, largest) and of the newest keyframe
    against the true poses ``truth`` ``(steps, 3)``."""
    estimate = mapper.graph.pose_array()
    n = len(estimate)
    if not n:
        return {"key_err_p50_cm": 0.0, "key_err_max_cm": 0.0, "newest_err_cm": 0.0}
    steps = mapper._fronts.view()[:n, 5].astype(int)
    err = np.hypot(*(estimate[:, :2] - truth[steps, :2]).T) * 100
    places = getattr(mapper, "places", None)
    held = places.keyframes_held()[:n] if places is not None else np.ones(n, dtype=bool)
    return {
        "key_err_p50_cm": round(float(np.median(err[held])), 2),
        "key_err_max_cm": round(float(err[held].max()), 2),
        "newest_err_cm": round(float(err[-1]), 2),
    }


def _rss_mb() -> float:
    """The process's resident memory now (MB; where ``/proc`` is missing, its peak)."""
    statm = Path("/proc/self/statm")
    if statm.exists():
        return int(statm.read_text().split()[1]) * resource.getpagesize() / 1e6
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--world", default="loop-block")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--laps", type=int, default=6)
    parser.add_argument("--every", type=int, default=1000, help="steps between two rows")
    parser.add_argument("--json", type=Path)
    parser.add_argument("--no-places", action="store_true", help="hold every keyframe scan and kept scan")
    args = parser.parse_args()
    walls_true = build_scene(args.world, args.seed).walls
    slot = PipelineSlot(laser_offset(f"sim:{args.world}"))
    config = PipelineConfig.parse({"loop_closure": {}})
    slot.start(config)
    online = slot.pipeline
    assert isinstance(online, OnlineGraphMapper)
    if args.no_places:  # as the agent builds it, places off
        online.close()
        online = OnlineGraphMapper(slot._make_pipeline, config, history=MAX_TRAJECTORY_POSES, places=False)
    rows = []
    header = False
    t0 = time.perf_counter()
    step = 0
    step_ms: list[float] = []
    truth = np.zeros((1024, 3))
    for step, (scan, pose) in enumerate(scene_patrol(args.world, seed=args.seed, laps=args.laps), 1):
        if step > len(truth):
            truth = np.vstack([truth, np.zeros_like(truth)])
        truth[step - 1] = pose.as_tuple()
        t_step = time.perf_counter()
        online.step(scan)
        step_ms.append((time.perf_counter() - t_step) * 1e3)
        if step % args.every == 0:
            rows.append(_row(online, walls_true, step, time.perf_counter() - t0, step_ms, truth))
            step_ms = []
            if not header:
                print("  ".join(f"{k:>10}" for k in rows[-1]))
                header = True
            print("  ".join(f"{v:>10}" for v in rows[-1].values()), flush=True)
    online.flush()
    online.wait_idle()
    rows.append(_row(online, walls_true, step, time.perf_counter() - t0, step_ms, truth))
    print("  ".join(f"{v:>10}" for v in rows[-1].values()), "(flushed)")
    if args.json is not None:
        args.json.write_text(json.dumps(rows, indent=1))
    online.close()


if __name__ == "__main__":
    main()
