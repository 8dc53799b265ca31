"""The correlative score surface's grid (shared/slam/surface.py) against the plain loop it replaces: the
sums skip the zero stretches of the look-up table's rows, and must come out the same bit for bit, windows
hanging over the table's edges and returns off the table included."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.slam.surface import ScoreSurface, _extents, _score_grid
from shared.types import FloatArray, Pose2D


def plain_grid(
    table: FloatArray,
    x0: float,
    y0: float,
    cell: float,
    cur: FloatArray,
    x: float,
    y: float,
    theta: float,
    n_rot: int,
    rot_step: float,
    n_xy: int,
) -> tuple[FloatArray, FloatArray]:
    """The whole window of every return added, cell by cell, in the returns' order (the reference)."""
    nx, ny = table.shape
    side = 2 * n_xy + 1
    best = np.full((side, side), -1.0)
    best_th = np.zeros((side, side))
    for k in range(-n_rot, n_rot + 1):
        th = theta + k * rot_step
        c, s = math.cos(th), math.sin(th)
        cx = [math.floor((c * p[0] - s * p[1] + x - x0) / cell) for p in cur]
        cy = [math.floor((s * p[0] + c * p[1] + y - y0) / cell) for p in cur]
        sums = np.zeros((side, side))
        for i in range(len(cur)):
            for a in range(side):
                u = cx[i] + a - n_xy
                if not 0 <= u < nx:
                    continue
                for b in range(side):
                    v = cy[i] + b - n_xy
                    if 0 <= v < ny:
                        sums[a, b] += table[u, v]
        for a in range(side):
            for b in range(side):
                score = sums[a, b] / len(cur)
                if score > best[a, b]:
                    best[a, b], best_th[a, b] = score, th
    return best, best_th


def sparse_table(draw: st.DrawFn) -> FloatArray:
    nx = draw(st.integers(1, 14))
    ny = draw(st.integers(1, 14))
    values = draw(
        st.lists(st.one_of(st.just(0.0), st.floats(0.001, 1.0)), min_size=nx * ny, max_size=nx * ny)
    )
    return np.array(values).reshape(nx, ny)


Case = tuple[FloatArray, FloatArray, float, float, float, int, int]


@st.composite
def cases(draw: st.DrawFn) -> Case:
    table = sparse_table(draw)
    n = draw(st.integers(1, 12))
    coords = st.floats(-0.6, 1.6, allow_nan=False)
    cur = np.array(draw(st.lists(st.tuples(coords, coords), min_size=n, max_size=n)))
    x = draw(st.floats(-0.3, 1.0))
    y = draw(st.floats(-0.3, 1.0))
    theta = draw(st.floats(-math.pi, math.pi))
    return table, cur, x, y, theta, draw(st.integers(0, 3)), draw(st.integers(0, 4))


@settings(max_examples=300, deadline=None)
@given(cases())
def test_the_grid_is_the_plain_loop_bit_for_bit(case: Case) -> None:
    table, cur, x, y, theta, n_rot, n_xy = case
    nx, ny = table.shape
    first, after = np.empty((nx, ny + 1), np.int64), np.empty((nx, ny + 1), np.int64)
    filled = np.zeros(nx, np.bool_)
    # the rows' extents filled by an earlier call elsewhere on the table serve a later one unchanged
    for dx in (0.0, 0.35, -0.2):
        got = _score_grid(
            table, first, after, filled, -0.05, -0.05, 0.1, cur, x + dx, y, theta, n_rot, 0.03, n_xy
        )
        want = plain_grid(table, -0.05, -0.05, 0.1, cur, x + dx, y, theta, n_rot, 0.03, n_xy)
        assert np.array_equal(got[0], want[0])
        assert np.array_equal(got[1], want[1])
    full_first, full_after = _extents(table)
    assert np.array_equal(first[filled], full_first[filled])
    assert np.array_equal(after[filled], full_after[filled])


@settings(max_examples=200, deadline=None)
@given(st.composite(lambda draw: sparse_table(draw))())
def test_extents_bound_the_nonzero_cells_of_each_row(table: FloatArray) -> None:
    first, after = _extents(table)
    nx, ny = table.shape
    for u in range(nx):
        nonzero = np.flatnonzero(table[u])
        for v in range(ny + 1):
            later = nonzero[nonzero >= v]
            earlier = nonzero[nonzero < v]
            assert first[u, v] == (later[0] if len(later) else ny)
            assert after[u, v] == (earlier[-1] + 1 if len(earlier) else 0)


def want_at(surface: ScoreSurface, pose: Pose2D) -> float:
    x0, y0 = float(surface.lo[0]), float(surface.lo[1])
    grid = plain_grid(
        surface.table, x0, y0, surface.cell, surface.cur, pose.x_m, pose.y_m, pose.theta_rad, 0, 0.0, 0
    )
    return float(grid[0][0, 0])


def test_a_room_surface_is_the_plain_loop() -> None:
    """A realistic case: the walls of a 6 x 4 m room as the submap, the same room seen from a pose 0.3 m
    and 0.1 rad off as the returns; the 10 cm surface of the loop search, as the plain loop gives it, and
    its best cell at the true shift."""
    rng = np.random.default_rng(3)
    t = rng.uniform(0.0, 1.0, 400)
    side = rng.integers(0, 4, 400)
    corners = np.array([[0.0, 0.0], [6.0, 0.0], [6.0, 4.0], [0.0, 4.0], [0.0, 0.0]])
    sub = corners[side] + (corners[side + 1] - corners[side]) * t[:, None]
    true = Pose2D(0.3, -0.2, 0.1)
    # the returns in the frame of ``true``: the submap's points moved by its inverse
    c, s = math.cos(true.theta_rad), math.sin(true.theta_rad)
    d = sub[::3] - [true.x_m, true.y_m]
    cur = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])
    guess = Pose2D(0.0, 0.0, 0.0)
    surface = ScoreSurface(sub, cur, guess, 0.1, 0.25, 0.5, clip_m=30.0)
    assert not surface.filled.any()
    assert surface.at(guess) == want_at(surface, guess)
    # the score of one pose reads one row a return: only those rows' extents were filled
    assert 0 < surface.filled.sum() <= len(np.unique(np.floor((surface.cur[:, 0] - surface.lo[0]) / 0.1)))
    got = surface.scores(guess, 6, 0.02)
    want = plain_grid(
        surface.table, float(surface.lo[0]), float(surface.lo[1]), 0.1, surface.cur, 0.0, 0.0, 0.0, 6, 0.02, 5
    )
    assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])
    a, b = np.unravel_index(int(np.argmax(got[0])), got[0].shape)
    assert (int(a) - 5, int(b) - 5) == (3, -2)
    assert abs(got[1][a, b] - 0.1) < 0.011
