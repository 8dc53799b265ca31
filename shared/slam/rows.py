"""Rows of numbers appended one at a time, kept in one array that doubles as it fills (amortised O(1) an
append), and thinned by position; the graph mapper's per-step and per-kept-scan records
(:mod:`shared.slam.mapper`). As arrays they cost a mapping state one copy each, not an object per row."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from shared.types import FloatArray

__all__ = ["Rows"]


class Rows:
    """``n`` rows of ``width`` float64 numbers, in the order appended."""

    __slots__ = ("data", "n")

    def __init__(self, width: int) -> None:
        self.data: FloatArray = np.zeros((16, width), dtype=np.float64)
        self.n = 0

    @classmethod
    def of(cls, rows: FloatArray) -> Rows:
        """Rows holding a copy of ``rows`` ``(n, width)``. O(n)."""
        out = cls(rows.shape[1])
        out.data = np.zeros((max(16, 2 * len(rows)), rows.shape[1]), dtype=np.float64)
        out.data[: len(rows)] = rows
        out.n = len(rows)
        return out

    def __len__(self) -> int:
        return self.n

    def append(self, row: Sequence[float]) -> None:
        """One row at the end. Amortised O(width)."""
        if self.n == len(self.data):
            grown = np.zeros((2 * len(self.data), self.data.shape[1]), dtype=np.float64)
            grown[: self.n] = self.data[: self.n]
            self.data = grown
        self.data[self.n] = row
        self.n += 1

    def view(self) -> FloatArray:
        """The rows ``(n, width)``, read-only (valid until the next append or drop)."""
        out = self.data[: self.n]
        out.setflags(write=False)
        return out

    def row(self, i: int) -> FloatArray:
        """Row ``i`` (negative counts from the end)."""
        out: FloatArray = self.data[: self.n][i]
        return out

    def drop(self, positions: Sequence[int]) -> None:
        """Remove the rows at ``positions`` (ascending). O(n)."""
        if not len(positions):
            return
        keep = np.ones(self.n, dtype=bool)
        keep[np.asarray(positions, dtype=np.intp)] = False
        kept = self.data[: self.n][keep]
        self.data = np.zeros((max(16, 2 * len(kept)), self.data.shape[1]), dtype=np.float64)
        self.data[: len(kept)] = kept
        self.n = len(kept)
