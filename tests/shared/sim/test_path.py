"""The speed-driven path: straight legs at constant speed, turns in place only at the knots."""

from __future__ import annotations

import itertools
import math
import re

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from shared.errors import InvalidInputError
from shared.sim import DEFAULT_KNOTS, default_path, plan_path
from shared.types import Pose2D, wrap_angle


def _steps(path: list[Pose2D]) -> tuple[list[float], list[float]]:
    moves = [math.hypot(b.x_m - a.x_m, b.y_m - a.y_m) for a, b in itertools.pairwise(path)]
    turns = [wrap_angle(b.theta_rad - a.theta_rad) for a, b in itertools.pairwise(path)]
    return moves, turns


def test_square_known_answer() -> None:
    # 1 m legs at 0.25 m/s and 10 Hz: 40 steps of 2.5 cm per leg;
    # 90 degree left turns at pi/2 rad/s: 10 steps of pi/20 per turn.
    knots = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    path = plan_path(knots, speed_mps=0.25, turn_rate_radps=math.pi / 2, rate_hz=10.0)
    assert len(path) == 1 + 3 * 40 + 2 * 10
    moves, turns = _steps(path)
    np.testing.assert_allclose([m for m in moves if m > 0], 0.025, rtol=1e-12)
    np.testing.assert_allclose([t for t in turns if t != 0.0], math.pi / 20, rtol=1e-9)
    assert path[0] == Pose2D(0.0, 0.0, 0.0)
    assert path[-1] == Pose2D(0.0, 1.0, math.pi)
    # the turn steps are in place, at the knots
    assert all(path[i].as_tuple()[:2] == (1.0, 0.0) for i in range(40, 51))


def test_last_step_of_a_leg_is_the_remainder() -> None:
    path = plan_path([[0.0, 0.0], [0.1, 0.0]], speed_mps=0.4, rate_hz=10.0)
    moves, _ = _steps(path)
    np.testing.assert_allclose(moves, [0.04, 0.04, 0.02], atol=1e-15)
    assert path[-1].x_m == 0.1


def test_turns_take_the_shorter_way() -> None:
    # heading 0 then heading -pi/2 (turn right), not +3pi/2
    path = plan_path([[0.0, 0.0], [1.0, 0.0], [1.0, -1.0]], turn_rate_radps=0.5, rate_hz=10.0)
    _, turns = _steps(path)
    rotations = [t for t in turns if t != 0.0]
    assert all(t < 0 for t in rotations)
    assert sum(rotations) == pytest.approx(-math.pi / 2)
    assert len(rotations) == math.ceil((math.pi / 2) / 0.05)


def test_default_path_is_the_planned_default_knots() -> None:
    path = default_path()
    moves, turns = _steps(path)
    knots = {tuple(k) for k in DEFAULT_KNOTS}
    assert 450 < len(path) < 600
    assert max(moves) == pytest.approx(0.04)
    for (a, b), turn in zip(itertools.pairwise(path), turns, strict=True):
        if abs(turn) > 1e-12:
            assert (a.x_m, a.y_m) in knots and (b.x_m, b.y_m) in knots
    assert (path[-1].x_m, path[-1].y_m) == DEFAULT_KNOTS[-1]
    # the legacy form still gives evenly spaced poses for the kernel tests
    assert len(default_path(50)) == 50


@pytest.mark.parametrize(
    ("kwargs", "fragment"),
    [
        ({"knots": [[0.0, 0.0]]}, "K >= 2"),
        ({"knots": [[0.0, 0.0], [1.0, 0.0], [1.0, 0.0]]}, "knots[2]"),
        ({"knots": [[0.0, 0.0], [np.nan, 0.0]]}, "non-finite"),
        ({"knots": [[0.0, 0.0], [1.0, 0.0]], "speed_mps": 0.0}, "speed_mps"),
        ({"knots": [[0.0, 0.0], [1.0, 0.0]], "rate_hz": math.inf}, "rate_hz"),
        ({"knots": [[0.0, 0.0], [1.0, 0.0]], "turn_rate_radps": -1.0}, "turn_rate_radps"),
    ],
)
def test_bad_arguments(kwargs: dict[str, object], fragment: str) -> None:
    with pytest.raises(InvalidInputError, match=re.escape(fragment)):
        plan_path(**kwargs)  # type: ignore[arg-type]


@settings(max_examples=60, deadline=None)
@given(
    knots=st.lists(st.tuples(st.floats(-20, 20), st.floats(-20, 20)), min_size=2, max_size=6),
    speed=st.floats(0.05, 2.0),
    turn_rate=st.floats(0.1, 3.0),
    rate=st.sampled_from([5.0, 10.0, 40.0]),
)
def test_motion_is_translation_or_rotation(
    knots: list[tuple[float, float]], speed: float, turn_rate: float, rate: float
) -> None:
    pts = np.array(knots)
    assume(np.all(np.hypot(*np.diff(pts, axis=0).T) > 1e-3))
    path = plan_path(pts, speed, turn_rate, rate)
    moves, turns = _steps(path)
    knot_set = {tuple(k) for k in pts.tolist()}
    for (a, _), move, turn in zip(itertools.pairwise(path), moves, turns, strict=True):
        assert move <= speed / rate * (1 + 1e-9)
        assert abs(turn) <= turn_rate / rate * (1 + 1e-9)
        if abs(turn) > 1e-9:  # heading changes only in place, on a knot
            assert move == 0.0 and (a.x_m, a.y_m) in knot_set
    # full-length steps everywhere but the last step of each leg
    short = sum(1 for m in moves if 0 < m < speed / rate * (1 - 1e-9))
    assert short <= len(pts) - 1
    assert (path[-1].x_m, path[-1].y_m) == tuple(pts[-1])
