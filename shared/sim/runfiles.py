"""Writing a :class:`SimRun` to disk as a log a real robot could have recorded, plus its ground truth.

Files in the run's directory:

- ``run.clf``: the scans and their odometry in CARMEN format (:func:`shared.io.carmen.write_carmen`);
- ``walls.json``: the world (:func:`shared.sim.load_world` reads it);
- ``poses.csv``: the true robot poses, header ``stamp,x,y,theta`` (s, m, m, rad);
- ``ticks.csv``: the cumulative encoder counts, header ``stamp,left,right`` (integer ticks).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from shared.sim.errors import WorldFileError
from shared.sim.run import SimRun
from shared.sim.worldfile import save_world
from shared.types import FloatArray

__all__ = ["POSES_HEADER", "read_poses", "write_run"]

logger = logging.getLogger(__name__)

POSES_HEADER = "stamp,x,y,theta"


def write_run(run: SimRun, directory: Path | str) -> dict[str, Path]:
    """Write ``run`` into ``directory`` (created if missing); returns the paths by kind.

    Keys: ``"clf"``, ``"walls"``, ``"poses"``, ``"ticks"``. Existing files of those names are replaced.
    O(N x beams).
    """
    from shared.io.carmen import write_carmen  # the I/O layer; imported here so shared.sim stays light

    directory = Path(directory)
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise WorldFileError(directory, f"cannot create the run directory: {exc}") from exc
    paths = {
        "clf": directory / "run.clf",
        "walls": directory / "walls.json",
        "poses": directory / "poses.csv",
        "ticks": directory / "ticks.csv",
    }
    write_carmen(paths["clf"], run.scans, laser_offset=run.drive.laser_offset)
    save_world(run.world, paths["walls"])
    stamps = run.stamps_s
    rows = [
        f"{t!r},{p.x_m!r},{p.y_m!r},{p.theta_rad!r}"
        for t, p in zip(stamps.tolist(), run.true_poses, strict=True)
    ]
    ticks = [
        f"{t!r},{left},{right}" for t, (left, right) in zip(stamps.tolist(), run.ticks.tolist(), strict=True)
    ]
    try:
        paths["poses"].write_text("\n".join([POSES_HEADER, *rows]) + "\n", encoding="utf-8")
        paths["ticks"].write_text("\n".join(["stamp,left,right", *ticks]) + "\n", encoding="utf-8")
    except OSError as exc:
        raise WorldFileError(directory, f"cannot write the run's CSV files: {exc}") from exc
    logger.info("wrote a simulated run of %d scans to %s", len(run), directory)
    return paths


def read_poses(path: Path | str) -> FloatArray:
    """Read a ``poses.csv`` of :func:`write_run`: ``(N, 4)`` rows ``[stamp_s, x_m, y_m, theta_rad]``."""
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise WorldFileError(path, f"cannot read the file: {exc}") from exc
    if not lines or lines[0].strip() != POSES_HEADER:
        raise WorldFileError(
            path, f"first line {lines[:1]!r}: expected the header {POSES_HEADER!r}", "line 1"
        )
    out = np.empty((len(lines) - 1, 4), dtype=np.float64)
    for i, line in enumerate(lines[1:]):
        try:
            values = [float(v) for v in line.split(",")]
        except ValueError:
            values = []
        if len(values) != 4 or not np.all(np.isfinite(values)):
            raise WorldFileError(path, f"{line!r}: expected 4 finite numbers", f"line {i + 2}")
        out[i] = values
    return out
