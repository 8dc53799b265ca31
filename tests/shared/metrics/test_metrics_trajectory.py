"""Absolute trajectory error: known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from shared.metrics import MetricInputError, absolute_trajectory_error


def test_identical_trajectories_have_no_error() -> None:
    poses = np.column_stack([np.linspace(0, 5, 20), np.zeros(20), np.linspace(-3, 3, 20)])
    err = absolute_trajectory_error(poses, poses)
    assert err.rmse_m == 0.0 and err.max_m == 0.0 and err.heading_rmse_rad == 0.0 and err.poses == 20


def test_known_offsets() -> None:
    truth = np.zeros((4, 3))
    est = np.array([[0.3, 0.4, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    err = absolute_trajectory_error(est, truth)
    assert err.max_m == pytest.approx(0.5) and err.mean_m == pytest.approx(0.125)
    assert err.rmse_m == pytest.approx(math.sqrt(0.25 / 4))


def test_heading_error_wraps_round() -> None:
    truth = np.array([[0.0, 0.0, math.pi - 0.01]])
    est = np.array([[0.0, 0.0, -math.pi + 0.01]])
    assert absolute_trajectory_error(est, truth).heading_rmse_rad == pytest.approx(0.02)


def test_mismatched_or_bad_input_is_refused() -> None:
    with pytest.raises(MetricInputError, match="as many"):
        absolute_trajectory_error(np.zeros((3, 3)), np.zeros((4, 3)))
    with pytest.raises(MetricInputError, match="estimate"):
        absolute_trajectory_error(np.zeros((3, 2)), np.zeros((3, 3)))
    with pytest.raises(MetricInputError, match="truth"):
        absolute_trajectory_error(np.zeros((1, 3)), np.full((1, 3), np.nan))
