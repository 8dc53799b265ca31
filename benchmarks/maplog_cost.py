"""What the delta log (server/maplog.py) adds to a map upload's write transaction: ``apply_upload`` of a
200-wall delta against ``maplog.append`` of its event and against the undo record ``apply_upload`` now
reads first (``server.maphistory.capture_undo``, timed by a second call of its own), each timed in the
same transactions, in-process on one database (``--db``: a PostgreSQL URL, or a fresh SQLite temp file by
default; a robot is added to it).

Exit 0 when it ran (figures, not pass/fail).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
import uuid
from pathlib import Path

from server.database import Database
from server.maphistory import capture_undo
from server.maplog import append
from server.mapstore import apply_upload
from server.migrate import upgrade
from server.models import Robot
from server.schemas import MapUpload

__all__ = ["main"]


def _upload(version: int, base: int | None, walls: int) -> MapUpload:
    return MapUpload.model_validate(
        {
            "version": version,
            "base_version": base,
            "stamp_s": 1.0,
            "segments": [[i, float(i), 0.0, float(i), 1.0 + version] for i in range(walls)],
            "removed": [],
            "centroids": [[0.0, 0.0]],
            "pose": [0.0, 0.0, 0.0],
            "trajectory": [[float(version), 0.0, 0.0, 0.0]],
        }
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--db", help="database URL [a fresh SQLite temp file]")
    p.add_argument("--uploads", type=int, default=1200, help="deltas applied [1200]")
    p.add_argument("--walls", type=int, default=200, help="walls per delta [200]")
    args = p.parse_args(argv)
    tmp = tempfile.TemporaryDirectory(prefix="linemap-maplog-")
    db = Database(args.db or f"sqlite:///{Path(tmp.name) / 'cost.db'}")
    upgrade(db.engine)
    with db.session() as s:
        robot = Robot(name=f"cost-{uuid.uuid4().hex[:8]}", token_hash=uuid.uuid4().hex)
        s.add(robot)
        s.flush()
        rid = robot.id
    with db.write_conn() as conn:
        apply_upload(conn, rid, _upload(1, None, args.walls), "v1")
    applying, logging, undoing = [], [], []
    for v in range(2, args.uploads + 2):
        up = _upload(v, v - 1, args.walls)
        with db.write_conn() as conn:
            tu = time.perf_counter()
            capture_undo(conn, rid, up)  # what apply_upload reads again inside
            t0 = time.perf_counter()
            applied = apply_upload(conn, rid, up, f"v{v}")
            t1 = time.perf_counter()
            assert applied.event is not None
            append(conn, rid, applied.event, undo=applied.undo)
            logging.append(time.perf_counter() - t1)
            applying.append(t1 - t0)
            undoing.append(t0 - tu)
    db.dispose()
    logging.sort()
    print(f"{db.url.split(':')[0]}: {args.uploads} deltas of {args.walls} walls, in-process")
    print(f"  apply_upload      median {statistics.median(applying) * 1e3:6.2f} ms  (undo record included)")
    print(f"  undo record alone median {statistics.median(undoing) * 1e3:6.2f} ms")
    print(
        f"  delta log append   median {statistics.median(logging) * 1e3:6.2f} ms  "
        f"p90 {logging[int(0.9 * (len(logging) - 1))] * 1e3:6.2f} ms"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
