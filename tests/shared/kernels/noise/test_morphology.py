"""Grid morphology (paper §3.2.2, eq. 17-23, Table 2) against scipy.ndimage on an equivalent dense grid."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from shared.errors import KernelParameterError
from shared.kernels import REGISTRY, NoiseResult
from shared.kernels.noise.elements import ELEMENTS, element_footprint, element_offsets
from shared.kernels.noise.morphology import Dilation, Erosion, MorphologyParams, Opening
from shared.types import FloatArray

KERNELS: list[tuple[type[Erosion] | type[Dilation] | type[Opening], Callable[..., Any]]] = [
    (Erosion, ndimage.binary_erosion),
    (Dilation, ndimage.binary_dilation),
    (Opening, ndimage.binary_opening),
]

Cells = set[tuple[int, int]]


def cells_of(points: FloatArray, size: float) -> Cells:
    return {(int(a), int(b)) for a, b in np.floor(points / size).astype(np.int64)}


def scipy_cells(points: FloatArray, size: float, psi: tuple[int, int, int], op: Callable[..., Any]) -> Cells:
    """The operation on a dense grid over the points' bounding box, zero-padded beyond the element's reach."""
    if len(points) == 0:
        return set()
    r = max(psi) + 1
    c = np.floor(points / size).astype(np.int64)
    lo = c.min(axis=0) - r
    grid = np.zeros(c.max(axis=0) - lo + r + 1, dtype=bool)
    grid[c[:, 0] - lo[0], c[:, 1] - lo[1]] = True
    out = op(grid, structure=element_footprint(psi))
    return {(int(a) + int(lo[0]), int(b) + int(lo[1])) for a, b in np.argwhere(out)}


def check_against_scipy(points: FloatArray, size: float, psi: tuple[int, int, int]) -> None:
    occupied = cells_of(points, size)
    for kernel_cls, op in KERNELS:
        res = kernel_cls(psi=psi, cell_size_m=size).apply(points)
        expected = scipy_cells(points, size, psi, op)
        assert cells_of(res.points, size) == expected, f"{kernel_cls.name} psi={psi}"
        n_kept = int(res.keep.sum())
        np.testing.assert_array_equal(res.points[:n_kept], points[res.keep])
        assert np.all(res.labels == 0)
        if kernel_cls is Dilation:
            assert res.keep.all()
            added = cells_of(res.points[n_kept:], size)
            assert len(added) == res.n_added
            assert not (added & occupied)
        else:
            assert res.n_added == 0
            # a point is kept iff its cell is in the result
            kept_cells = np.floor(points / size).astype(np.int64)
            inside = np.array([(int(a), int(b)) in expected for a, b in kept_cells], dtype=bool)
            np.testing.assert_array_equal(res.keep, inside)


# --- structuring elements (Table 2, Fig. 10, eq. 19) --------------------------------------------------


def test_named_elements() -> None:
    dense = element_footprint(ELEMENTS["DENSEx3"])
    assert dense.shape == (3, 3)
    assert dense.all()
    plus4 = element_footprint(ELEMENTS["PLUSx4"])
    np.testing.assert_array_equal(plus4, [[0, 1, 0], [1, 1, 1], [0, 1, 0]])
    dx, dy = element_offsets(ELEMENTS["PLUSx8"])
    eq19 = {(-2, 0), (-1, 0), (0, 0), (1, 0), (2, 0), (0, -1), (0, -2), (0, 1), (0, 2)}
    assert set(zip(dx.tolist(), dy.tolist(), strict=True)) == eq19
    assert len(dx) == 9
    star = element_footprint(ELEMENTS["STARx8"])
    assert star.sum() == 17
    assert star[0, 0]
    assert star[4, 0]
    assert star[2, 2]
    assert not star[1, 0]


@given(psi=st.tuples(st.integers(0, 5), st.integers(0, 5), st.integers(0, 5)))
def test_element_size_and_symmetry(psi: tuple[int, int, int]) -> None:
    dx, dy = element_offsets(psi)
    pairs = set(zip(dx.tolist(), dy.tolist(), strict=True))
    assert len(pairs) == len(dx) == 1 + 2 * psi[0] + 2 * psi[1] + 4 * psi[2]
    assert pairs == {(-a, -b) for a, b in pairs}  # B = B^S (eq. 23)
    assert (dx[0], dy[0]) == (0, 0)


def test_element_parameters() -> None:
    assert Opening(element="densex3").params.element == "DENSEx3"
    assert Opening(element="STARX8").params.vector() == (2, 2, 2)
    assert Opening().params.vector() == (1, 1, 0)
    assert Opening(element="DENSEx3", psi=[0, 3, 1]).params.vector() == (0, 3, 1)  # psi wins
    rebuilt = Opening(Opening(psi=(1, 2, 3)).get_params())
    assert rebuilt.params.vector() == (1, 2, 3)
    with pytest.raises(KernelParameterError, match="element"):
        Opening(element="CROSSx5")
    for bad in [(6, 0, 0), (0, -1, 0), (1, 1)]:
        with pytest.raises(KernelParameterError, match="psi"):
            Erosion(psi=bad)
    with pytest.raises(KernelParameterError, match="cell_size_m"):
        Dilation(cell_size_m=0.0)
    assert "psi" in MorphologyParams.model_json_schema()["properties"]
    for name in ("erosion", "dilation", "opening"):
        assert REGISTRY.get("noise-removal", name).name == name


# --- against scipy.ndimage ---------------------------------------------------------------------------


@pytest.mark.parametrize("element", list(ELEMENTS))
def test_named_elements_match_scipy(element: str) -> None:
    rng = np.random.default_rng(7)
    blob = rng.normal(0.0, 0.06, (600, 2))
    wall = np.column_stack([np.linspace(-1.0, 1.0, 800), rng.normal(0.3, 0.01, 800)])
    specks = rng.uniform(-1.0, 1.0, (30, 2))
    check_against_scipy(np.concatenate([blob, wall, specks]), 0.02, ELEMENTS[element])


@settings(max_examples=60, deadline=None)
@given(
    cells=st.lists(st.tuples(st.integers(-12, 12), st.integers(-12, 12)), min_size=0, max_size=250),
    psi=st.tuples(st.integers(0, 5), st.integers(0, 5), st.integers(0, 5)),
    seed=st.integers(0, 2**32 - 1),
)
def test_random_sets_and_elements_match_scipy(cells: list[tuple[int, int]], psi: tuple[int, int, int],
                                              seed: int) -> None:
    size = 0.05
    rng = np.random.default_rng(seed)
    base = np.array(cells, dtype=np.float64).reshape(-1, 2)
    pts = (base + rng.uniform(0.05, 0.95, base.shape)) * size  # one or more points inside each listed cell
    check_against_scipy(pts, size, psi)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 800),
       psi=st.tuples(st.integers(0, 3), st.integers(0, 3), st.integers(0, 3)))
def test_dense_random_clouds_match_scipy(seed: int, n: int, psi: tuple[int, int, int]) -> None:
    rng = np.random.default_rng(seed)
    check_against_scipy(rng.normal(0.0, 0.1, (n, 2)), 0.02, psi)


# --- sparse grid, edge cases, behaviour -----------------------------------------------------------------


def test_far_apart_groups_behave_as_if_alone() -> None:
    """Groups 1000 km apart (a dense grid would need ~1e16 cells) give the same result as each alone."""
    rng = np.random.default_rng(3)
    near = rng.normal(0.0, 0.05, (400, 2))
    far = rng.normal(0.0, 0.05, (400, 2)) + np.array([1.0e6, -2.0e6])
    check_against_scipy(far, 0.02, (1, 1, 0))
    for kernel_cls, _ in KERNELS:
        a, b = kernel_cls().apply(near), kernel_cls().apply(far)
        both = kernel_cls().apply(np.concatenate([near, far]))
        np.testing.assert_array_equal(both.keep, np.concatenate([a.keep, b.keep]))
        assert both.n_added == a.n_added + b.n_added


def test_nonfinite_rows_are_dropped_and_empty_input() -> None:
    pts = np.array([[0.0, 0.0], [np.nan, 0.0], [0.01, 0.0], [np.inf, np.inf]])
    pts.setflags(write=False)
    for kernel_cls, _ in KERNELS:
        res: NoiseResult = kernel_cls(psi=(0, 0, 0)).apply(pts)  # the identity element
        np.testing.assert_array_equal(res.keep, [True, False, True, False])
        assert res.n_added == 0
        empty = kernel_cls().apply(np.zeros((0, 2)))
        assert empty.keep.shape == (0,)
        assert empty.points.shape == (0, 2)
    one = Dilation().apply(np.array([[0.01, 0.01]]))
    assert one.keep.all()
    assert one.n_added == 4


def noisy_wall_with_outliers(seed: int, angle: float) -> tuple[FloatArray, int]:
    """A 3 m wall sampled every 2 mm (accumulated scans) with sigma 1 cm noise, plus 40 isolated outliers."""
    rng = np.random.default_rng(seed)
    s = np.arange(0.0, 3.0, 0.002)
    d = np.array([np.cos(angle), np.sin(angle)])
    n = np.array([-d[1], d[0]])
    wall = s[:, None] * d + rng.normal(0.0, 0.01, s.size)[:, None] * n + [0.3, -0.7]
    outliers = wall[rng.integers(0, len(wall), 40)] + n * rng.choice([-1.0, 1.0], 40)[:, None] \
        * rng.uniform(0.15, 1.0, 40)[:, None]
    return np.concatenate([wall, outliers]), len(wall)


def test_opening_removes_isolated_outliers_and_keeps_the_wall() -> None:
    kept = []
    for seed, angle in enumerate([0.0, 0.4, np.pi / 4, 2.0]):
        pts, n_wall = noisy_wall_with_outliers(seed, angle)
        res = Opening().apply(pts)  # defaults: PLUSx4, 2 cm cells
        assert not res.keep[n_wall:].any(), "isolated outliers must go"
        kept.append(res.keep[:n_wall].mean())
        eroded = Erosion().apply(pts)
        assert eroded.keep.sum() < res.keep.sum()  # the dilation step gives wall points back
        assert np.all(res.keep[eroded.keep])
    # the wall centre lies on a cell boundary for angle 0: the worst case of the grid alignment
    assert min(kept) > 0.5
    assert np.mean(kept) > 0.7
