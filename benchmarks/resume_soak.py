"""Soak of the agent's resume (robot_agent.resume): a real ``linemap agent`` process maps the simulator
(``--laps``, as fast as it can, no server) and is killed with SIGKILL ``--kills`` times at random versions,
each time restarted on the same Robot DB, then runs to the end. The Robot DB's trajectory and walls are
compared with one pipeline stepped through the same scans in this process. Prints the kills, the largest
pose difference (m, degrees), versions lost or repeated, walls missing or extra, the journal's rows and the
Robot DB's size.

    .venv/bin/python benchmarks/resume_soak.py [--kills 200] [--laps 3] [--seed 0]
"""

from __future__ import annotations

import argparse
import math
import random
import signal
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from robot_agent.sources import laser_offset, open_scans
from shared.pipeline import Pipeline, PipelineConfig

__all__ = ["main"]

LINEMAP = str(Path(sys.executable).parent / "linemap")


def _version(db: Path) -> int:
    try:
        with sqlite3.connect(db) as conn:
            row = conn.execute("SELECT value FROM meta WHERE key = 'map_version'").fetchone()
    except sqlite3.Error:
        return 0
    return 0 if row is None else int(row[0].split(":")[1].strip(" }"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--kills", type=int, default=200)
    parser.add_argument("--laps", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = random.Random(args.seed)
    reference = Pipeline(PipelineConfig(), laser_offset=laser_offset("sim"))
    for scan in open_scans("sim", seed=0, laps=args.laps):
        reference.step(scan)
    n = reference.version
    db = Path(tempfile.mkdtemp()) / "robot.db"
    cmd = [LINEMAP, "agent", "--db", str(db), "--rate", "0", "--laps", str(args.laps)]
    log = db.with_suffix(".log").open("ab")
    t0 = time.monotonic()
    kills = 0
    while kills < args.kills:
        start = _version(db)
        if start >= n - 5:
            break
        target = min(n - 2, start + rng.randint(1, max(2, (n - start) // max(1, args.kills - kills))))
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        while _version(db) < target and proc.poll() is None:
            time.sleep(0.01)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        kills += 1
    proc = subprocess.Popen([*cmd, "--exit-at-end"], stdout=log, stderr=subprocess.STDOUT)
    proc.wait()
    log.close()
    with sqlite3.connect(db) as conn:
        poses = np.array(
            conn.execute("SELECT version, x_m, y_m, theta_rad FROM poses ORDER BY version").fetchall()
        )
        walls = {int(r[0]): r[1:] for r in conn.execute("SELECT * FROM walls")}
        journal = conn.execute("SELECT count(*) FROM scan_journal").fetchone()[0]
    ref = reference.snapshot()
    versions = poses[:, 0].astype(int)
    lost = sorted(set(range(1, n + 1)) - set(versions.tolist()))
    repeated = len(versions) - len(set(versions.tolist()))
    d_xy = float(np.abs(poses[:, 1:3] - ref.trajectory[versions - 1, 1:3]).max())
    d_th = np.remainder(poses[:, 3] - ref.trajectory[versions - 1, 3] + math.pi, 2 * math.pi) - math.pi
    ref_walls = {int(i): s for i, s in zip(ref.segment_ids, ref.segments, strict=True)}
    missing = sorted(set(ref_walls) - set(walls))
    extra = sorted(set(walls) - set(ref_walls))
    far = max(
        (float(np.abs(np.asarray(walls[i]) - ref_walls[i]).max()) for i in set(walls) & set(ref_walls)),
        default=0.0,
    )
    print(
        f"{kills} kills over {n} versions in {time.monotonic() - t0:.0f} s",
        f"(agent log {db.with_suffix('.log')})",
    )
    print(f"largest pose difference: {d_xy * 100:.3f} cm, {math.degrees(float(np.abs(d_th).max())):.4f} deg")
    print(
        f"versions lost: {len(lost)}, repeated: {repeated}; walls {len(walls)} (reference {len(ref_walls)}), "
        f"missing {len(missing)}, extra {len(extra)}, largest wall difference {far * 100:.3f} cm"
    )
    print(f"scan journal rows at the end: {journal}; Robot DB {db.stat().st_size / 1e6:.1f} MB")


if __name__ == "__main__":
    main()
