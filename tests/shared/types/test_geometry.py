"""Hesse normal form, segments and point sets."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from shared.errors import InvalidInputError
from shared.types import LineSegment, as_points, canonical_hesse, hesse_from_endpoints, segments_from_hesse

coord = st.floats(-50.0, 50.0, allow_nan=False)


@given(coord, coord, coord, coord)
def test_endpoints_lie_on_their_hesse_line(x0: float, y0: float, x1: float, y1: float) -> None:
    rho, theta = hesse_from_endpoints([[x0, y0, x1, y1]])
    assert 0.0 <= theta[0] < math.pi
    for x, y in ((x0, y0), (x1, y1)):
        assert abs(x * math.cos(theta[0]) + y * math.sin(theta[0]) - rho[0]) < 1e-6


@given(st.floats(-20, 20), st.floats(-20, 20))
def test_canonical_hesse_is_the_same_line(rho: float, theta: float) -> None:
    r2, t2 = canonical_hesse(rho, theta)
    assert 0.0 <= float(t2) < math.pi
    # the same set of points: a point on the original line lies on the canonical one
    px, py = rho * math.cos(theta), rho * math.sin(theta)
    assert abs(px * math.cos(float(t2)) + py * math.sin(float(t2)) - float(r2)) < 1e-6


def test_seam_equivalence() -> None:
    r, t = canonical_hesse([1.5], [math.pi + 0.1])
    assert math.isclose(float(r[0]), -1.5) and math.isclose(float(t[0]), 0.1)


@given(st.floats(-10, 10), st.floats(0, math.pi - 1e-6), st.floats(-5, 5), st.floats(-5, 5))
def test_segments_from_hesse_round_trip(rho: float, theta: float, t0: float, t1: float) -> None:
    seg = segments_from_hesse(rho, theta, t0, t1)
    assert seg.shape == (1, 4)
    if abs(t1 - t0) > 1e-3:
        r2, th2 = hesse_from_endpoints(seg)
        same = abs(th2[0] - theta) < 1e-6 and abs(r2[0] - rho) < 1e-6
        flipped = abs(abs(th2[0] - theta) - math.pi) < 1e-6 and abs(r2[0] + rho) < 1e-6
        assert same or flipped


def test_line_segment() -> None:
    seg = LineSegment(0.0, 1.0, 2.0, 1.0)
    assert seg.length_m == 2.0
    rho, theta = seg.hesse
    assert math.isclose(theta, math.pi / 2) and math.isclose(rho, 1.0)
    again = LineSegment.from_hesse(rho, theta, -1.0, 1.0)
    assert math.isclose(again.length_m, 2.0)


def test_as_points_validates_shape() -> None:
    assert as_points([]).shape == (0, 2)
    with pytest.raises(InvalidInputError, match=r"expected \(N, 2\)"):
        as_points(np.zeros((3, 3)))
