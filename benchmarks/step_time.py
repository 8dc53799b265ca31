"""Online step time on the default simulated world and whole-log replay throughput, against a baseline tree.

The speed targets (docs/worlds.md, "Speed"): the online step median <= 3 ms on the default world, and a
whole-log replay (reading and writing included, as ``linemap map`` does it) >= 300 scans/s. Each measurement
runs in its own process (numba caches warm, the first step not counted); with ``--baseline DIR`` (an exported
older tree, e.g. ``git archive <commit> | tar -x -C DIR``) the baseline and this tree alternate ``--repeats``
times in the same session, and the medians and their ratio are printed, since the shared machine drifts by
20-40 % between runs; with ``--loop-closure`` too, the baseline also runs with loop closure and that ratio
is printed as well.

    .venv/bin/python benchmarks/step_time.py [--baseline DIR] [--repeats 3] [--log mit-csail/mit-csail.clf.gz]
        [--loop-closure]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

__all__ = ["main", "measure"]

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / ".." / "shared" / "data"


def measure(log: Path, loop_closure: bool = False) -> dict[str, float]:
    """Step median (ms) over the default world's scans, and the scans/s of ``linemap map``'s own path over
    ``log``: reading it, mapping it, and writing the GeoJSON map and the trajectory CSV, in this process
    (the first step, which compiles, not counted). With ``loop_closure`` the step is the robot's
    (:class:`shared.slam.OnlineGraphMapper`, its search and redraws on the worker thread; the step's own
    wall time, the worker competing for the cores) and the replay ``linemap map``'s with loop closure."""
    import tempfile

    try:
        from shared.mapping import map_scans, open_source, write_outputs
    except ImportError:  # a baseline tree from before offline mapping left the CLI package
        from shared.cli.mapping import map_scans, open_source, write_outputs  # type: ignore[no-redef]
    from shared.pipeline import Pipeline, PipelineConfig
    from shared.sim import default_world, simulate_run

    run = simulate_run(default_world(), seed=0)
    settings = None
    if loop_closure:
        from shared.slam import LoopClosureSettings, OnlineGraphMapper

        settings = LoopClosureSettings()
        offset = run.drive.laser_offset
        online = OnlineGraphMapper(lambda c: Pipeline(c, laser_offset=offset), PipelineConfig(), settings)
        times = []
        for scan in run.scans:
            t0 = time.perf_counter()
            online.step(scan)
            times.append((time.perf_counter() - t0) * 1e3)
        online.wait_idle(600)
        online.close()
        step_ms = statistics.median(times[1:])
    else:
        pipe = Pipeline(laser_offset=run.drive.laser_offset)
        for scan in run.scans:
            pipe.step(scan)
        step_ms, _ = pipe.timing_ms()
    marks: list[float] = []

    def on_step(n: int) -> None:
        if n == 1:  # the first step compiles: not throughput
            marks.append(time.perf_counter())

    with tempfile.TemporaryDirectory() as out:
        source = open_source(str(log))
        mapped = map_scans(source, PipelineConfig(), on_step=on_step, loop_closure=settings)
        write_outputs(mapped.snapshot, geojson=Path(out) / "map.geojson", trajectory=Path(out) / "poses.csv")
        seconds = time.perf_counter() - marks[0]
    count = mapped.scans
    return {"step_median_ms": step_ms, "replay_scans_per_s": (count - 1) / seconds if seconds > 0 else 0.0}


def _child(tree: Path | None, log: Path, loop_closure: bool = False) -> dict[str, float]:
    env = dict(os.environ)
    if tree is not None:
        env["PYTHONPATH"] = str(tree)
    out = subprocess.run(
        [sys.executable, __file__, "--child", "--log", str(log)]
        + (["--loop-closure"] if loop_closure else []),
        env=env,
        check=True,
        capture_output=True,
        text=True,
        cwd=tree or ROOT,
    )
    return dict(json.loads(out.stdout.strip().splitlines()[-1]))


def main(argv: list[str] | None = None) -> int:
    """Command line (module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--baseline", type=Path, help="an exported older tree to compare against")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--log", default="mit-csail/mit-csail.clf.gz", help="under ../shared/data")
    parser.add_argument(
        "--loop-closure",
        action="store_true",
        help="this tree with loop closure on as well (the robot's step, linemap map's replay)",
    )
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    log = Path(args.log) if Path(args.log).is_absolute() else DATA / args.log
    if not log.exists():
        parser.error(f"log {log} not found: expected a file under ../shared/data or an absolute path")
    if args.child:
        print(json.dumps(measure(log, args.loop_closure)))
        return 0
    if args.baseline is not None and not (args.baseline / "shared").is_dir():
        parser.error(f"--baseline {args.baseline} holds no shared/ package: expected an exported tree")
    trees: list[tuple[str, Path | None, bool]] = [("this tree", None, False)]
    if args.baseline is not None:
        trees.insert(0, ("baseline", args.baseline.resolve(), False))
    if args.loop_closure:
        if args.baseline is not None:
            trees.insert(1, ("baseline + loop", args.baseline.resolve(), True))
        trees.append(("+ loop closure", None, True))
    runs: dict[str, list[dict[str, float]]] = {name: [] for name, _, _ in trees}
    for i in range(args.repeats):
        for name, tree, loop in trees:
            runs[name].append(_child(tree, log, loop))
            print(f"run {i + 1}/{args.repeats} {name}: {runs[name][-1]}", file=sys.stderr)
    med = {name: {key: statistics.median(r[key] for r in rs) for key in rs[0]} for name, rs in runs.items()}
    print(f"{'tree':15s} {'step median ms':>15s} {'replay scans/s':>15s}   ({args.repeats} runs, {log.name})")
    for name, m in med.items():
        print(f"{name:15s} {m['step_median_ms']:15.2f} {m['replay_scans_per_s']:15.0f}")
    if args.baseline is not None:
        b, t = med["baseline"], med["this tree"]
        print(
            f"{'ratio':15s} {t['step_median_ms'] / b['step_median_ms']:15.2f}x "
            f"{t['replay_scans_per_s'] / b['replay_scans_per_s']:14.2f}x"
        )
        if args.loop_closure:
            b, t = med["baseline + loop"], med["+ loop closure"]
            print(
                f"{'ratio, loop':15s} {t['step_median_ms'] / b['step_median_ms']:15.2f}x "
                f"{t['replay_scans_per_s'] / b['replay_scans_per_s']:14.2f}x"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
