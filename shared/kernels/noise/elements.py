"""Structuring elements for the morphology kernels (paper §3.2.2, eq. 17-19, Table 2, Fig. 10).

An element is given by the vector ``V = (psi_H, psi_V, psi_C)`` (eq. 17) of arm lengths in grid cells: it
holds the centre, the horizontal arm ``(i, 0)`` for ``1 <= |i| <= psi_H``, the vertical arm ``(0, j)`` for
``1 <= |j| <= psi_V`` and both diagonals ``(k, k)`` and ``(k, -k)`` for ``1 <= |k| <= psi_C``. Offsets are
``(x, y)`` cell steps. Every such element is symmetric (``B = B^S``, eq. 23), so erosion and dilation need no
reflection. The paper's ``+-`` signs only say that each arm is two-sided; a negative entry means the same
as its absolute value.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from shared.kernels.noise._cellhash import Int64Array
from shared.kernels.results import freeze
from shared.types import BoolArray

__all__ = ["ELEMENTS", "MAX_PSI", "canonical_element", "element_footprint", "element_offsets"]

#: Named elements of Table 2 as ``(psi_H, psi_V, psi_C)``.
ELEMENTS: dict[str, tuple[int, int, int]] = {
    "DENSEx3": (1, 1, 1),  # Fig. 10(a): the full 3 x 3 block
    "PLUSx4": (1, 1, 0),  # Fig. 10(b): centre and its 4 neighbours
    "PLUSx8": (2, 2, 0),  # Fig. 10(c): eq. 19
    "STARx8": (2, 2, 2),  # Fig. 10(d): PLUSx8 plus both diagonals of length 2
}

#: Largest arm length accepted for an explicit ``psi`` vector.
MAX_PSI = 5

_BY_LOWER = {name.lower(): name for name in ELEMENTS}


def canonical_element(name: str) -> str:
    """The Table 2 spelling of an element name given in any case (``"plusx4"`` -> ``"PLUSx4"``).

    Raises ``ValueError`` naming the known elements otherwise.
    """
    canonical = _BY_LOWER.get(name.strip().lower())
    if canonical is None:
        raise ValueError(f"unknown structuring element {name!r}: expected one of {', '.join(ELEMENTS)}")
    return canonical


@lru_cache(maxsize=64)
def element_offsets(psi: tuple[int, int, int]) -> tuple[Int64Array, Int64Array]:
    """Cell offsets ``(dx, dy)`` (read-only int64 arrays) of the element ``psi``; the centre comes first.

    ``|B| = 1 + 2|psi_H| + 2|psi_V| + 4|psi_C|`` offsets, no duplicates. Cached per ``psi``.
    """
    h, v, c = (abs(int(p)) for p in psi)
    offsets: list[tuple[int, int]] = [(0, 0)]
    offsets += [(i, 0) for i in range(-h, h + 1) if i != 0]
    offsets += [(0, j) for j in range(-v, v + 1) if j != 0]
    offsets += [(k, k) for k in range(-c, c + 1) if k != 0]
    offsets += [(k, -k) for k in range(-c, c + 1) if k != 0]
    arr = np.array(offsets, dtype=np.int64)
    dx = np.ascontiguousarray(arr[:, 0])
    dy = np.ascontiguousarray(arr[:, 1])
    freeze(dx, dy)
    return dx, dy


def element_footprint(psi: tuple[int, int, int]) -> BoolArray:
    """The element as a dense boolean ``(2r+1, 2r+1)`` array, ``r = max |psi|``, indexed ``[r + dx, r + dy]``.

    This is the ``structure`` argument that ``scipy.ndimage`` expects (centre at ``[r, r]``).
    """
    dx, dy = element_offsets(psi)
    r = int(max(abs(int(p)) for p in psi))
    out = np.zeros((2 * r + 1, 2 * r + 1), dtype=np.bool_)
    out[r + dx, r + dy] = True
    return out
