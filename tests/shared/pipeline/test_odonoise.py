"""The learned odometry noise (shared.pipeline.odonoise): it finds the factor a robot's odometry really has,
only from what the scan fixes, robustly, and the pipeline then follows good wheels along a corridor."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from shared.pipeline.odonoise import NoiseScale, OdometryNoise

MODEL = np.diag([1.0 / 0.02**2, 1.0 / 0.02**2, 1.0 / 0.01**2])  # 2 cm, 0.01 rad
#: a corridor along x: the scan fixes y and the heading to 1 mm / 1e-4 rad, x only to 1 m
CORRIDOR = np.diag([1.0, 1.0 / 0.001**2, 1.0 / 1e-4**2])


def feed(noise: OdometryNoise, sigmas: tuple[float, float, float], n: int, seed: int = 0) -> None:
    rng = np.random.default_rng(seed)
    for _ in range(n):
        e = rng.normal(0.0, sigmas)
        noise.update(*noise.ratios(e, CORRIDOR, MODEL))


@pytest.mark.parametrize("factor", [0.1, 1.0, 9.0])
def test_it_learns_the_variance_factor_of_the_innovations(factor: float) -> None:
    noise = OdometryNoise()
    s = factor**0.5
    feed(noise, (0.02 * s, 0.02 * s, 0.01 * s), 200)
    assert noise.scale.translation == pytest.approx(factor, rel=0.35)
    assert noise.scale.heading == pytest.approx(factor, rel=0.35)


def test_a_direction_the_scan_does_not_fix_teaches_nothing() -> None:
    noise = OdometryNoise()
    # large errors along the corridor (x), none across it: along x the scan cannot tell odometry wrong
    feed(noise, (0.5, 0.02, 0.01), 200)
    assert noise.scale.translation == pytest.approx(1.0, rel=0.35)


def test_the_model_holds_until_enough_matches_are_in() -> None:
    noise = OdometryNoise(min_samples=20)
    feed(noise, (0.2, 0.2, 0.1), 19)
    assert noise.scale == NoiseScale()
    feed(noise, (0.2, 0.2, 0.1), 1)
    assert noise.scale.translation > 10.0


def test_a_few_slip_bursts_do_not_inflate_the_noise() -> None:
    noise = OdometryNoise()
    feed(noise, (0.02, 0.02, 0.01), 180)
    feed(noise, (1.0, 1.0, 0.5), 20, seed=1)  # 10 % of the matches: wheels spinning on the spot
    assert noise.scale.translation < 2.0 and noise.scale.heading < 2.0


def test_an_inconsistent_match_is_far_in_the_learned_units() -> None:
    noise = OdometryNoise()
    feed(noise, (0.005, 0.005, 0.0025), 200)  # wheels four times better than the model
    r_xy, r_th = noise.ratios(np.array([0.0, 0.03, 0.0]), CORRIDOR, MODEL)  # 3 cm across: 6 learned sigma
    m2, dof = noise.consistency(r_xy, r_th)
    assert dof == 2 and m2 > 25.0
    assert OdometryNoise().consistency(r_xy, r_th)[0] < 3.0  # under the model alone: 1.5 sigma


def test_an_uninvertible_scan_information_is_ignored() -> None:
    noise = OdometryNoise()
    assert noise.ratios(np.zeros(3), np.zeros((3, 3)), MODEL) == (None, None)


@settings(max_examples=50, deadline=None)
@given(st.floats(0.05, 1e4), st.floats(0.05, 1e4))
def test_factors_stay_within_bounds(a: float, b: float) -> None:
    noise = OdometryNoise(min_samples=1, window=5)
    feed(noise, (0.02 * a**0.5, 0.02 * a**0.5, 0.01 * b**0.5), 5)
    k = noise.scale
    assert 0.05 <= k.translation <= 1e4 and 0.05 <= k.heading <= 1e4


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(0.0, 100.0), min_size=1, max_size=60), st.integers(1, 20))
def test_the_factor_is_the_median_of_the_last_window_ratios(values: list[float], window: int) -> None:
    noise = OdometryNoise(min_samples=1, window=window, floor=0.0, ceiling=1e9)
    for v in values:
        noise.update(v, v)
    expected = float(np.median(values[-window:])) / 0.454936
    assert noise.scale.translation == pytest.approx(expected)
    assert noise.scale.heading == pytest.approx(expected)
    assert noise.samples == (min(len(values), window),) * 2
