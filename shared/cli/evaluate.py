"""``linemap eval``: the docs/design.md §5 measures of a map written by ``linemap map``, as plain figures."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from shared.errors import LinemapError
from shared.sim import World, default_world, load_world

__all__ = ["evaluate", "load_truth"]


def load_truth(spec: str) -> World:
    """``sim`` (the default world) or a world file (JSON/TOML walls)."""
    return default_world() if spec == "sim" else load_world(Path(spec))


def evaluate(
    map_path: Path, *, walls: str | None = None, trajectory: Path | None = None, relations: Path | None = None
) -> dict[str, Any]:
    """Every measure the inputs allow: line accuracy and area error need ``walls`` (area error also the
    trajectory, to know which side of the walls is inside); relation error needs trajectory and relations."""
    from shared.export import read_geojson_segments, read_trajectory_csv
    from shared.metrics import (
        MapLeakError,
        MetricError,
        area_error_pct,
        line_accuracy,
        read_relations,
        relation_error,
    )

    if walls is None and relations is None:
        raise LinemapError("nothing to measure against: give --walls (ground truth) and/or --relations")
    if relations is not None and trajectory is None:
        raise LinemapError(
            "--relations needs --trajectory (the CSV written by `linemap map --trajectory-out`)"
        )
    segments = read_geojson_segments(map_path)
    figures: dict[str, Any] = {"map": str(map_path), "segments": len(segments)}
    stamps = poses = None
    if trajectory is not None:
        stamps, poses = read_trajectory_csv(trajectory)
    if walls is not None:
        world = load_truth(walls)
        figures["line_accuracy"] = line_accuracy(segments, world.walls).as_dict()
        if poses is not None:
            try:
                figures["area_error_pct"] = area_error_pct(segments, world.floor_area_m2, poses[:, :2])
            except (MapLeakError, MetricError) as exc:
                figures["area_error_pct"] = None
                figures["area_error_note"] = str(exc)
    if relations is not None and stamps is not None and poses is not None:
        rel = relation_error(stamps, poses, read_relations(relations))
        figures["relation_error"] = {
            "relations": rel.n_relations,
            "used": rel.n_used,
            "unmatched": rel.n_unmatched,
            "trans_mean_m": rel.trans_mean_m,
            "trans_std_m": rel.trans_std_m,
            "rot_mean_deg": rel.rot_mean_deg,
            "rot_std_deg": rel.rot_std_deg,
        }
    return figures
