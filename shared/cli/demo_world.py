"""The world ``linemap demo`` patrols (``--world``) and the picture of its map (``--png``).

``room`` is the paper's Fig. 8 room (the agent's ``sim`` source); any kind of the scenario suite
(:data:`shared.sim.worlds.KINDS`, drawn with seed 0 as the agent does) is patrolled out and back with its
people, doors and odometry errors (``sim:KIND``); a world file (``.json``/``.toml``) is patrolled as
``sim:FILE``. :func:`save_map_png` fetches the robot's latest map from the server and draws it over the
world's true walls.
"""

from __future__ import annotations

from pathlib import Path

import httpx
import numpy as np

from shared.errors import LinemapError
from shared.types import FloatArray, Pose2D

__all__ = ["DEFAULT_WORLD", "save_map_png", "true_walls", "world_names", "world_source"]

#: The demo's world unless ``--world`` says otherwise: the paper's room, as before the suite.
DEFAULT_WORLD = "room"
_FILE_SUFFIXES = (".json", ".toml")


def world_names() -> list[str]:
    """What ``--world`` accepts by name: ``room`` and the suite's kinds, in the suite's order."""
    from shared.sim.worlds import KINDS

    return [DEFAULT_WORLD, *KINDS]


def world_source(world: str) -> str:
    """The agent's ``--source`` for ``--world world``; :class:`LinemapError` naming the bad value and
    listing the kinds when it is neither a known world nor an existing world file."""
    if world == DEFAULT_WORLD:
        return "sim"
    if world in world_names():
        return f"sim:{world}"
    if Path(world).suffix.lower() in _FILE_SUFFIXES:
        if not Path(world).is_file():
            raise LinemapError(f"--world {world!r}: no such world file")
        return f"sim:{Path(world).resolve()}"
    raise LinemapError(
        f"--world {world!r}: unknown world; expected one of {', '.join(world_names())} "
        "(`linemap bench worlds --list` describes them) or a world file (.json/.toml)"
    )


def true_walls(world: str, t_s: float) -> FloatArray:
    """The true walls ``(W, 4)`` m of ``world`` at scene time ``t_s`` (a door opened by then is open)."""
    if world == DEFAULT_WORLD:
        from shared.sim import default_world

        return default_world().walls
    if world in world_names():
        from shared.sim.worlds import build_scene

        return build_scene(world, 0).truth(t_s)[0].walls
    from shared.sim import load_world

    return load_world(Path(world)).walls


def save_map_png(base_url: str, token: str, robot_id: int, world: str, path: Path) -> str:
    """Draw robot ``robot_id``'s latest map (``GET /api/v1/robots/{id}/maps/latest``) over the true walls
    of ``world`` (grey) to the PNG ``path``; returns a one-line summary (version, walls, scans)."""
    from shared.export import render_map
    from shared.pipeline import MapSnapshot

    try:
        r = httpx.get(
            f"{base_url}/api/v1/robots/{robot_id}/maps/latest",
            headers={"Authorization": f"Bearer {token}"},
            timeout=30.0,
        )
    except httpx.TransportError as exc:
        raise LinemapError(f"could not fetch the robot's map for {path}: {exc}") from None
    if r.status_code != 200:
        raise LinemapError(f"could not fetch the robot's map for {path}: HTTP {r.status_code} {r.text[:200]}")
    m = r.json()
    rows = np.asarray(m["segments"], dtype=np.float64).reshape(-1, 5)
    trajectory = np.asarray(m["trajectory"], dtype=np.float64).reshape(-1, 4)
    snapshot = MapSnapshot(
        version=int(m["version"]),
        stamp_s=float(m["stamp_s"]),
        segments=rows[:, 1:],
        segment_ids=rows[:, 0].astype(np.intp),
        centroids=np.asarray(m["centroids"], dtype=np.float64).reshape(-1, 2),
        pose=Pose2D(*m["pose"]),
        trajectory=trajectory,
    )
    minutes = snapshot.stamp_s / 60.0
    title = f"linemap demo, {Path(world).name}: {len(rows)} walls after {minutes:.1f} min"
    render_map(snapshot, path, walls=true_walls(world, snapshot.stamp_s), title=title)
    return f"{len(rows)} walls, map version {snapshot.version}, {minutes:.1f} min of patrol"
