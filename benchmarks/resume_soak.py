"""Soak of the agent's resume (robot_agent.resume): a real ``linemap agent`` process maps ``--source`` (the
simulator, ``--laps`` times, or a log file) as fast as it can, with no server, and is killed with SIGKILL
``--kills`` times at random versions, each time restarted on the same Robot DB, then runs to the end. An
uninterrupted agent maps the same source into a Robot DB of its own, and the two are compared: every
version's pose, the walls (ids and end points) and, with ``--loop-closure``, the pose graph's keyframes
and closures. Prints the kills, the largest differences (cm, degrees), versions lost or repeated, walls
missing or extra, the journal's rows and the Robot DB's size.

    .venv/bin/python benchmarks/resume_soak.py [--kills 200] [--laps 3] [--seed 0]
    .venv/bin/python benchmarks/resume_soak.py --loop-closure --source LOG  # e.g. mit-csail.clf.gz
"""

from __future__ import annotations

import argparse
import json
import math
import random
import signal
import sqlite3
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["main"]

#: the Robot DB records a keyframe again only once it moved 1 mm or 1 mrad (robot_agent.mapping), so its
#: rows may lag the graph by that much; the graphs themselves are compared after a restore

LINEMAP = str(Path(sys.executable).parent / "linemap")


def _meta(db: Path, key: str) -> Any:
    try:
        with sqlite3.connect(db) as conn:
            row = conn.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
    except sqlite3.Error:
        return None
    return None if row is None else json.loads(row[0])["v"]


def _version(db: Path) -> int:
    return int(_meta(db, "map_version") or 0)


def _read(db: Path) -> dict[str, Any]:
    """What the comparison needs from a Robot DB: poses by version, walls by id, keyframes, closures."""
    with sqlite3.connect(db) as conn:
        poses = np.array(
            conn.execute("SELECT version, x_m, y_m, theta_rad FROM poses ORDER BY version").fetchall()
        ).reshape(-1, 4)
        walls = {int(r[0]): np.asarray(r[1:5], dtype=float) for r in conn.execute("SELECT * FROM walls")}
        journal = conn.execute("SELECT count(*) FROM scan_journal").fetchone()[0]
    keyframes = {int(r[0]): np.asarray(r[2:5], dtype=float) for r in _meta(db, "graph_keyframes") or []}
    closures = sorted(tuple(c) for c in _meta(db, "graph_loop_closures") or [])
    return {"poses": poses, "walls": walls, "journal": journal, "keyframes": keyframes, "closures": closures}


def _graph_rows(db: Path, source: str) -> np.ndarray:
    """The keyframes ``[id, stamp, x, y, theta]`` of the graph a restart would resume from ``db`` (its
    state and journal; pending searches joined), exactly as the agent's mapper held them."""
    from robot_agent.mapping import PipelineSlot, RecentScans
    from robot_agent.resume import Checkpoints
    from robot_agent.sources import laser_offset
    from robot_agent.store import RobotDB
    from shared.pipeline import PipelineConfig
    from shared.slam import OnlineGraphMapper

    store = RobotDB(db)
    slot = PipelineSlot(laser_offset(source))
    try:
        slot.start(PipelineConfig.model_validate(store.get("config")))
        resumed = Checkpoints(store).resume(slot, RecentScans())
        if resumed.problem is not None:
            raise SystemExit(f"{db}: {resumed.problem}")
        graph = slot.pipeline
        assert isinstance(graph, OnlineGraphMapper)
        graph.flush()
        return np.array(graph.keyframe_rows())
    finally:
        slot.close()
        store.close()


def _turn_deg(a: np.ndarray, b: np.ndarray) -> float:
    d = np.remainder(np.asarray(a) - np.asarray(b) + math.pi, 2 * math.pi) - math.pi
    return math.degrees(float(np.abs(d).max(initial=0.0)))


def _soak(cmd: list[str], db: Path, n: int, kills_wanted: int, rng: random.Random) -> int:
    log = db.with_suffix(".log").open("ab")
    kills = 0
    while kills < kills_wanted:
        start = _version(db)
        if start >= n - 5:
            break
        target = min(n - 2, start + rng.randint(1, max(2, (n - start) // max(1, kills_wanted - kills))))
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        while _version(db) < target and proc.poll() is None:
            time.sleep(0.01)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        kills += 1
        if kills % 20 == 0:
            print(f"  {kills} kills, version {_version(db)} of {n}", flush=True)
    subprocess.run([*cmd, "--exit-at-end"], stdout=log, stderr=subprocess.STDOUT, check=True)
    log.close()
    return kills


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--kills", type=int, default=200)
    parser.add_argument("--source", default="sim")
    parser.add_argument("--laps", type=int, default=3, help="the simulator's laps")
    parser.add_argument("--loop-closure", action="store_true")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = random.Random(args.seed)
    tmp = Path(tempfile.mkdtemp())
    base = [LINEMAP, "agent", "--rate", "0", "--source", args.source]
    base += ["--laps", str(args.laps)] if args.source.startswith("sim") else []
    base += ["--loop-closure"] if args.loop_closure else []
    t0 = time.monotonic()
    ref_db, db = tmp / "uninterrupted.db", tmp / "killed.db"
    with ref_db.with_suffix(".log").open("ab") as out:
        subprocess.run([*base, "--db", str(ref_db), "--exit-at-end"], stdout=out, stderr=out, check=True)
    n = _version(ref_db)
    print(f"uninterrupted: {n} versions in {time.monotonic() - t0:.0f} s", flush=True)
    t1 = time.monotonic()
    kills = _soak([*base, "--db", str(db)], db, n, args.kills, rng)
    ref, got = _read(ref_db), _read(db)
    versions = got["poses"][:, 0].astype(int)
    lost = sorted(set(range(1, n + 1)) - set(versions.tolist()))
    repeated = len(versions) - len(set(versions.tolist()))
    ref_pose = {int(r[0]): r[1:] for r in ref["poses"]}
    common = [v for v in versions.tolist() if v in ref_pose]
    a = np.array([ref_pose[v] for v in common]).reshape(-1, 3)
    b = np.array([got["poses"][versions == v][0, 1:] for v in common]).reshape(-1, 3)
    print(f"{kills} kills over {n} versions in {time.monotonic() - t1:.0f} s (logs in {tmp})")
    print(
        f"poses: largest difference {float(np.abs(a[:, :2] - b[:, :2]).max(initial=0.0)) * 100:.4f} cm, "
        f"{_turn_deg(a[:, 2], b[:, 2]):.5f} deg; versions lost {len(lost)}, repeated {repeated}"
    )
    missing = sorted(set(ref["walls"]) - set(got["walls"]))
    extra = sorted(set(got["walls"]) - set(ref["walls"]))
    both = set(ref["walls"]) & set(got["walls"])
    far = max((float(np.abs(ref["walls"][i] - got["walls"][i]).max()) for i in both), default=0.0)
    print(
        f"walls {len(got['walls'])} (uninterrupted {len(ref['walls'])}): missing {len(missing)}, "
        f"extra {len(extra)}, largest end-point difference {far * 100:.4f} cm"
    )
    if args.loop_closure:
        keys = sorted(set(ref["keyframes"]) & set(got["keyframes"]))
        ka = np.array([ref["keyframes"][k] for k in keys]).reshape(-1, 3)
        kb = np.array([got["keyframes"][k] for k in keys]).reshape(-1, 3)
        print(
            f"keyframes {len(got['keyframes'])} (uninterrupted {len(ref['keyframes'])}): largest difference "
            f"{float(np.hypot(*(ka[:, :2] - kb[:, :2]).T).max(initial=0.0)) * 100:.4f} cm, "
            f"{_turn_deg(ka[:, 2], kb[:, 2]):.5f} deg; loop closures {len(got['closures'])} "
            f"(uninterrupted {len(ref['closures'])}, the same: {got['closures'] == ref['closures']})"
        )
        a, b = _graph_rows(ref_db, args.source), _graph_rows(db, args.source)
        same = a.shape == b.shape and bool(np.array_equal(a, b))
        far = float(np.hypot(*(a[:, 2:4] - b[:, 2:4]).T).max()) if a.shape == b.shape else math.inf
        print(
            "the graphs restored from both Robot DBs: keyframes the same bit for bit:",
            f"{same} (largest difference {far * 100:.6f} cm)",
        )
    print(f"scan journal rows at the end: {got['journal']}; Robot DB {db.stat().st_size / 1e6:.1f} MB")


if __name__ == "__main__":
    main()
