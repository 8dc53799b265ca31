"""A sparse set of integer grid cells: open-addressing hash table in numba (private to the noise kernels).

Points are binned into square cells ``floor(p / size)``; the occupied cells are numbered in order of first
appearance and stored in a linear-probing hash table keyed by the cell's ``(ix, iy)`` pair. Memory and time
are O(N) in the number of points, independent of the area the points cover (a 30 m x 30 m batch at 2 cm
cells would be a 2.25 M-cell dense grid; here it costs one table of ~2N slots).

Cell indices are clipped to ``+-2**60`` before the float to int conversion, so absurd coordinates cannot
overflow; clipping is monotone and 1-Lipschitz, hence neighbouring cells stay neighbours.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from shared.kernels._jit import njit
from shared.types import FloatArray

__all__ = ["Int64Array", "cell_indices"]

Int64Array = NDArray[np.int64]

_CLIP = float(2**60)


def cell_indices(points: FloatArray, size: float) -> tuple[Int64Array, Int64Array]:
    """Integer cells ``(ix, iy)`` (int64, ``(N,)`` each) of finite ``(N, 2)`` points; cell side ``size`` m.

    O(N). ``ix = floor(x / size)`` clipped to ``+-2**60``.
    """
    q = np.floor(points / size)
    np.clip(q, -_CLIP, _CLIP, out=q)
    cells = q.astype(np.int64)
    return np.ascontiguousarray(cells[:, 0]), np.ascontiguousarray(cells[:, 1])


@njit
def _slot(ix: int, iy: int, mask: int) -> int:
    """Hash of a cell, reduced to a table slot (multiplicative hashing with wrapping int64 arithmetic)."""
    h = ix * np.int64(-7046029254386353131) + iy * np.int64(-4658895280553007687)
    h ^= h >> 29
    h *= np.int64(-4417276706812531889)
    h ^= h >> 32
    return int(h & mask)


@njit
def _build(ix: Int64Array, iy: Int64Array) -> tuple[Int64Array, Int64Array, Int64Array, Int64Array]:
    """Number the distinct cells of ``(ix[k], iy[k])`` in order of first appearance.

    Returns ``(cell, ucx, ucy, table)``: ``cell[k]`` is the number of entry ``k``'s cell, ``ucx``/``ucy`` the
    distinct cells, ``table`` the hash table (``-1`` = empty slot, size a power of two >= 2 * entries).
    Expected O(N).
    """
    n = ix.size
    size = 2
    while size < 2 * n:
        size *= 2
    mask = size - 1
    table = np.full(size, -1, dtype=np.int64)
    ucx = np.empty(n, dtype=np.int64)
    ucy = np.empty(n, dtype=np.int64)
    cell = np.empty(n, dtype=np.int64)
    m = 0
    for k in range(n):
        x = ix[k]
        y = iy[k]
        s = _slot(x, y, mask)
        while True:
            c = table[s]
            if c < 0:
                table[s] = m
                ucx[m] = x
                ucy[m] = y
                cell[k] = m
                m += 1
                break
            if ucx[c] == x and ucy[c] == y:
                cell[k] = c
                break
            s = (s + 1) & mask
    return cell, ucx[:m], ucy[:m], table


@njit
def _find(table: Int64Array, ucx: Int64Array, ucy: Int64Array, x: int, y: int) -> int:
    """Number of cell ``(x, y)`` in a table from :func:`_build`, or ``-1`` if unoccupied. O(1) expected."""
    mask = table.size - 1
    s = _slot(x, y, mask)
    while True:
        c = table[s]
        if c < 0:
            return -1
        if ucx[c] == x and ucy[c] == y:
            return int(c)
        s = (s + 1) & mask
