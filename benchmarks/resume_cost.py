"""The agent step's extra cost for resuming (robot_agent.resume), on the default simulated world: each step
is recorded twice, in turn, into two Robot DB files: as before (map version, walls, pose, outbox) and with
the scan journaled and, every ``--every`` steps, the mapping state saved. Taking the state (done in the
step) and making its bytes (done on a background thread by the agent; here in line) are timed apart.
Prints medians and 99th percentiles (ms), the state's size, and the pipeline step's own median for scale;
the two recordings alternate, so a loaded machine slows both alike.

    .venv/bin/python benchmarks/resume_cost.py [--loop-closure] [--laps 1] [--every 50]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from robot_agent.journal import scan_to_bytes
from robot_agent.mapping import PipelineSlot
from robot_agent.sources import laser_offset, open_scans
from robot_agent.store import RobotDB, SavedState, StepRecord
from shared.pipeline import PipelineConfig

__all__ = ["main"]


def _ms(values: list[float]) -> str:
    return f"median {statistics.median(values):7.3f}  p99 {float(np.percentile(values, 99)):7.3f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--loop-closure", action="store_true")
    parser.add_argument("--laps", type=int, default=1)
    parser.add_argument("--every", type=int, default=50, help="steps between two saved states")
    args = parser.parse_args()
    slot = PipelineSlot(laser_offset("sim"))
    slot.start(PipelineConfig.parse({"loop_closure": {}}) if args.loop_closure else PipelineConfig())
    tmp = Path(tempfile.mkdtemp())
    before, after = RobotDB(tmp / "before.db"), RobotDB(tmp / "after.db")
    step, plain, journaled, state, to_bytes, sizes = [], [], [], [], [], []
    for v, scan in enumerate(open_scans("sim", seed=0, laps=args.laps), 1):
        t0 = time.perf_counter()
        pose = slot.pipeline.step(scan).pose
        step.append((time.perf_counter() - t0) * 1e3)
        rec = StepRecord(v, scan.stamp_s, v, [], [], [scan.stamp_s, pose.x_m, pose.y_m, pose.theta_rad], [])
        t0 = time.perf_counter()
        before.record_step(rec)
        plain.append((time.perf_counter() - t0) * 1e3)
        t0 = time.perf_counter()
        blob, saved = scan_to_bytes(scan), None
        if v % args.every == 1:
            s0 = time.perf_counter()
            mapper_state = slot.pipeline.state()
            s1 = time.perf_counter()
            saved = SavedState(v, mapper_state.kind, mapper_state.format, 0, mapper_state.to_bytes())
            state.append((s1 - s0) * 1e3)
            to_bytes.append((time.perf_counter() - s1) * 1e3)
            sizes.append(len(saved.state))
        after.record_step(rec, blob, saved)
        journaled.append((time.perf_counter() - t0) * 1e3)
    slot.close()
    mode = "loop closure" if args.loop_closure else "front end"
    print(f"{len(step)} steps of the default world ({mode}), a state every {args.every} steps")
    print(f"pipeline step                      {_ms(step)}")
    print(f"record a step as before            {_ms(plain)}")
    print(f"record with journal (+ state)      {_ms(journaled)}")
    print(f"take a state (in the step)         {_ms(state)}")
    print(f"its bytes (background thread)      {_ms(to_bytes)}  last {sizes[-1] / 1e3:.0f} kB")
    for db in (before, after):
        db.close()


if __name__ == "__main__":
    main()
