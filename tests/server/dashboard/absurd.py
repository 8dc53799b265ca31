"""Stored maps no robot should have sent, written straight into a server's database (as an older server
stored them): absurd coordinates, and 130,000 long overlapping walls. Shared by the browser test and
``benchmarks/dashboard_big_map.py``."""

from __future__ import annotations

import json
import math
import random
from typing import Any

from sqlalchemy import text

from tests.server.live import Live

__all__ = ["login", "store_absurd_map", "store_big_map"]


def _new_map(live: Live, rid: int, version: int, pose: tuple[float, float, float], centroids: Any) -> None:
    with live.state.db.write_conn() as conn:
        conn.execute(
            text(
                "INSERT INTO map_states (robot_id, version, stamp_s, centroids, pose, updated_at) "
                "VALUES (:r, :v, 0.0, :c, :p, CURRENT_TIMESTAMP)"
            ),
            {
                "r": rid,
                "v": version,
                "c": json.dumps({"xy": centroids}),
                "p": json.dumps({"x_m": pose[0], "y_m": pose[1], "theta_rad": pose[2]}),
            },
        )
        conn.execute(text("UPDATE robots SET map_version = :v WHERE id = :r"), {"v": version, "r": rid})


def _walls(live: Live, rid: int, rows: list[tuple[int, float, float, float, float]]) -> None:
    with live.state.db.write_conn() as conn:
        conn.execute(
            text(
                "INSERT INTO map_segments (robot_id, segment_id, x0_m, y0_m, x1_m, y1_m, version) "
                "VALUES (:r, :s, :x0, :y0, :x1, :y1, 1)"
            ),
            [{"r": rid, "s": s, "x0": a, "y0": b, "x1": c, "y1": d} for s, a, b, c, d in rows],
        )


def store_absurd_map(live: Live) -> int:
    """A robot whose stored map has a wall at x = 1e20 m, one from -1e300 to 1e300 m, one at infinity,
    a 62-bit id, a
    centroid at 1e300 m, trajectory poses at 1e20 m and the pose at -1e20 m, beside a normal room."""
    rid, _ = live.new_robot()
    _new_map(live, rid, 3, (-1e20, 5.0, 1e9), [[1.0, 1.0], [1e300, 0.0]])
    _walls(
        live,
        rid,
        [
            (1, 0.0, 0.0, 4.0, 0.0),
            (2, 4.0, 0.0, 4.0, 3.0),
            (3, 1e20, 0.0, 1e20 + 5.0, 1.0),
            (4, -1e300, -1e300, 1e300, 1e300),
            (5, float("inf"), 0.0, 1.0, 1.0),  # reaches the page as null
            (2**62, 0.0, 3.0, 4.0, 3.0),
        ],
    )
    with live.state.db.write_conn() as conn:
        conn.execute(
            text(
                "INSERT INTO trajectory_points (robot_id, version, stamp_s, x_m, y_m, theta_rad) "
                "VALUES (:r, 3, :t, :x, :y, 0.0)"
            ),
            [{"r": rid, "t": float(i), "x": x, "y": 1.0} for i, x in enumerate([1.0, 1e20, 2.0, -1e20])],
        )
    return rid


def store_big_map(
    live: Live,
    n_walls: int = 130_000,
    seed: int = 18,
    centroids: int = 0,
    poses: int = 0,
    half_m: float = 100.0,
) -> int:
    """A robot whose stored map has ``n_walls`` long walls criss-crossing a square of ``2 * half_m`` metres
    (by default 200 m, walls 20-200 m long), and ``centroids`` centroids and a trajectory of ``poses``
    poses (a spiral) in it."""
    rid, _ = live.new_robot()
    rng = random.Random(seed)
    rows = []
    for i in range(n_walls):
        x0, y0 = rng.uniform(-half_m, half_m), rng.uniform(-half_m, half_m)
        x1, y1 = rng.uniform(-half_m, half_m), rng.uniform(-half_m, half_m)
        rows.append((i, x0, y0, x1, y1))
    for start in range(0, n_walls, 10_000):
        _walls(live, rid, rows[start : start + 10_000])
    xy = [[rng.uniform(-half_m, half_m), rng.uniform(-half_m, half_m)] for _ in range(centroids)]
    _new_map(live, rid, 1, (0.0, 0.0, 0.0), xy)
    if poses:
        spiral = [
            (
                0.1 * i,
                0.9 * half_m * i / poses * math.cos(i / 50),
                0.9 * half_m * i / poses * math.sin(i / 50),
            )
            for i in range(poses)
        ]
        with live.state.db.write_conn() as conn:
            conn.execute(
                text(
                    "INSERT INTO trajectory_points (robot_id, version, stamp_s, x_m, y_m, theta_rad) "
                    "VALUES (:r, 1, :t, :x, :y, 0.0)"
                ),
                [{"r": rid, "t": t, "x": x, "y": y} for t, x, y in spiral],
            )
    return rid


def login(page: Any, live: Live) -> None:
    """Log the page in as the operator (the dashboard's login form)."""
    page.goto(live.base_url + "/")
    page.get_by_test_id("login-token").fill(live.admin_token)
    page.get_by_test_id("login-submit").click()
    page.get_by_test_id("login-token").wait_for(state="detached")
