"""A typed wrapper around numba's ``njit`` for the kernels' inner loops.

Compiled functions are cached on disk (``cache=True``), so the compile cost is paid once per machine.
numba is a hard dependency: there is no second, pure-Python code path to drift out of sync.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, TypeVar, cast

import numba

__all__ = ["njit"]

F = TypeVar("F", bound=Callable[..., Any])


def njit(fn: F) -> F:
    """Compile ``fn`` in nopython mode, lazily on first call, cached on disk, releasing the GIL."""
    return cast(F, numba.njit(cache=True, nogil=True)(fn))
