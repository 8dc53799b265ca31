"""Reading Kümmerle et al. (2009) ``.relations`` files: the SLAM benchmark's ground truth (docs/design.md §5,
§8).

A line is ``t1 t2 x y z roll pitch yaw``: the true pose of the robot at time ``t2`` expressed in its frame
at ``t1`` (metres, radians, seconds; ``data/README.md``). Only ``x``, ``y`` and ``yaw`` are used in 2D.
Blank lines and lines starting with ``#`` are skipped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from shared.metrics.errors import MetricError, RelationsFormatError
from shared.types import FloatArray

__all__ = ["Relations", "parse_relations", "read_relations"]

_FIELDS = ("t1", "t2", "x", "y", "z", "roll", "pitch", "yaw")


@dataclass(frozen=True, slots=True, eq=False)
class Relations:
    """``N`` ground-truth relative poses: ``(x_m, y_m, yaw_rad)`` of the robot at ``t2_s`` in its frame at
    ``t1_s``. Arrays are read-only, shape ``(N,)``; ``source`` names where they came from."""

    t1_s: FloatArray
    t2_s: FloatArray
    x_m: FloatArray
    y_m: FloatArray
    yaw_rad: FloatArray
    source: str = "<relations>"

    def __post_init__(self) -> None:
        n = len(self.t1_s)
        for name in ("t1_s", "t2_s", "x_m", "y_m", "yaw_rad"):
            arr = np.array(getattr(self, name), dtype=np.float64, copy=True).reshape(-1)
            if len(arr) != n:
                raise MetricError(f"Relations.{name} has {len(arr)} values: expected {n}, like t1_s")
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    def __len__(self) -> int:
        return len(self.t1_s)


def parse_relations(text: str, *, source: str = "<string>") -> Relations:
    """Parse the text of a ``.relations`` file; raise :class:`RelationsFormatError` with the line number.

    Each data line needs exactly 8 finite numbers. O(lines).
    """
    rows: list[tuple[float, float, float, float, float]] = []
    for number, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        fields = stripped.split()
        if len(fields) != len(_FIELDS):
            raise RelationsFormatError(
                source, number, f"{len(fields)} fields: expected 8 ({' '.join(_FIELDS)})"
            )
        values: list[float] = []
        for name, field in zip(_FIELDS, fields, strict=True):
            try:
                value = float(field)
            except ValueError:
                raise RelationsFormatError(source, number, f"{name} = {field!r} is not a number") from None
            if not math.isfinite(value):
                raise RelationsFormatError(source, number, f"{name} = {field!r}: expected a finite number")
            values.append(value)
        rows.append((values[0], values[1], values[2], values[3], values[7]))
    arr = np.array(rows, dtype=np.float64).reshape(-1, 5)
    return Relations(arr[:, 0], arr[:, 1], arr[:, 2], arr[:, 3], arr[:, 4], source=source)


def read_relations(path: str | Path) -> Relations:
    """Read a ``.relations`` file (UTF-8 / ASCII text); errors name the file and line. O(lines)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise MetricError(f"{p}: relations file not found") from None
    except UnicodeDecodeError as exc:
        raise MetricError(f"{p}: not a text relations file ({exc.reason} at byte {exc.start})") from None
    except OSError as exc:
        raise MetricError(f"{p}: cannot read relations file: {exc.strerror or exc}") from None
    return parse_relations(text, source=str(p))
