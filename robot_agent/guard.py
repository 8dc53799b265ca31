"""Run-time protection for hot-swapped kernels during their probation.

:func:`guarded` subclasses a downloaded kernel class so that each ``apply`` is timed and checked, and a
raised exception never escapes: the call is answered by ``fallback`` (the kernel it replaced) instead, so
the step completes and no scan is lost, and ``on_failure`` is told, after which the agent rolls the kernel
back. A result that fails the stage's result checks (:func:`shared.kernels.conformance.check_result`: type,
shapes, non-finite values; issue 9 item 4) is treated the same way: it never reaches the map. A call
slower than ``budget_ms`` also counts as a failure (its result is still used). Overhead: one
``perf_counter`` pair and one O(N) result check per call.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from shared.kernels import Kernel, Stage
from shared.kernels.conformance import check_result

__all__ = ["guarded"]


def guarded(
    cls: type[Kernel[Any]],
    fallback: Callable[[], Kernel[Any]],
    on_failure: Callable[[type[Kernel[Any]], str], None],
    budget_ms: float,
) -> type[Kernel[Any]]:
    """A subclass of ``cls`` with the same stage, name, version and parameters, guarded as above."""
    base: Any = cls

    class Guarded(base):  # type: ignore[misc]
        def apply(self, *args: Any, **kwargs: Any) -> Any:
            t0 = time.perf_counter()
            try:
                out = super().apply(*args, **kwargs)
            except Exception as exc:
                on_failure(cls, f"{cls.name} {cls.version} raised {type(exc).__name__}: {exc}")
                return fallback().apply(*args, **kwargs)  # type: ignore[attr-defined]
            elapsed_ms = (time.perf_counter() - t0) * 1e3
            problems = check_result(cls.stage, out, _n_in(cls.stage, args, kwargs))
            if problems:
                shown = "; ".join(problems[:3])
                on_failure(cls, f"{cls.name} {cls.version} returned a bad result: {shown}"[:500])
                return fallback().apply(*args, **kwargs)  # type: ignore[attr-defined]
            if elapsed_ms > budget_ms:
                on_failure(
                    cls,
                    f"{cls.name} {cls.version} took {elapsed_ms:.1f} ms, over its {budget_ms:g} ms budget",
                )
            return out

    Guarded.__name__ = cls.__name__
    Guarded.__qualname__ = cls.__qualname__
    Guarded.__doc__ = cls.__doc__
    Guarded.__module__ = cls.__module__
    return Guarded


def _n_in(stage: Stage | str, args: tuple[Any, ...], kwargs: dict[str, Any]) -> int:
    """Input points of a call, for the stages whose result checks need it (noise removal, clustering)."""
    if Stage(stage) not in (Stage.NOISE_REMOVAL, Stage.CLUSTERING):
        return 0
    points = args[0] if args else next(iter(kwargs.values()), ())
    try:
        return len(points)
    except TypeError:
        return 0
