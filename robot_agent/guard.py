"""Run-time protection for hot-swapped kernels, for as long as they run.

:func:`guarded` subclasses a downloaded kernel class (the agent passes the class of
:func:`robot_agent.kernels.proc.remote_class`, whose code runs in a confined worker process) so that each
``apply`` is timed and checked, and a failure never escapes: the call is answered by ``fallback`` (the
kernel it replaced) instead, so the step completes and no scan is lost, and ``on_failure`` is told, after
which the agent rolls the kernel back. Failures:

- the kernel raised, or ran out of its memory limit in the worker (:class:`~robot_agent.kernels.proc.
  KernelCallError`), or any other exception;
- the worker hung past its per-call limit or died (:class:`~robot_agent.kernels.proc.WorkerError`): the
  supervisor has killed it already; the kernel is never called again (``on_stuck`` is told too);
- a result that fails the stage's result checks (:func:`shared.kernels.conformance.check_result`: type,
  shapes, non-finite values): it never reaches the map;
- ``overruns`` calls in a row slower than ``budget_ms`` (their results are still used): a kernel that is
  slow, not one call that met a busy moment of the machine (a single call over 200 ms, beside a load average
  over 2, rolled good kernels back: docs/reliability/netfault.md).

A hang in the worker cannot stop the agent: the calling thread waits on a socket with a deadline, and the
worker is a separate process (it may hold its own GIL forever). Overhead per call here: one
``perf_counter`` pair and one O(N) result check; the worker round trip is measured by
benchmarks/guard_overhead.py.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from typing import Any

from robot_agent.kernels.proc import KernelCallError, WorkerError
from shared.errors import LinemapError
from shared.kernels import Kernel, Stage
from shared.kernels.conformance import check_result

__all__ = ["guarded"]


def guarded(
    cls: type[Kernel[Any]],
    fallback: Callable[[], Kernel[Any]],
    on_failure: Callable[[type[Kernel[Any]], str], None],
    budget_ms: float,
    *,
    on_stuck: Callable[[type[Kernel[Any]], str], None] | None = None,
    overruns: int = 3,
    clock: Callable[[], float] = time.perf_counter,
) -> type[Kernel[Any]]:
    """A subclass of ``cls`` with the same stage, name, version and parameters, guarded as above
    (``clock``: seconds, for tests)."""
    if overruns < 1:
        raise ValueError(f"overruns={overruns}: expected at least 1 call over the budget before a rollback")
    base: Any = cls
    state: dict[str, Any] = {"stuck": None, "over": 0}

    def stuck(reason: str) -> None:
        if state["stuck"] is None:
            state["stuck"] = reason
            on_failure(cls, reason)
            if on_stuck is not None:
                on_stuck(cls, reason)

    class Guarded(base):  # type: ignore[misc]
        def __init__(self, params: Any = None, /, **overrides: Any) -> None:
            try:
                super().__init__(params, **overrides)
            except (WorkerError, KernelCallError) as exc:  # construction ran in a worker that failed
                if isinstance(exc, WorkerError):
                    stuck(exc.reason)
                else:
                    on_failure(cls, exc.reason)
                values = dict(params or {}) if not hasattr(params, "model_dump") else params.model_dump()
                self._params = cls.Params.model_construct(**{**values, **overrides})

        def _fallback(self, *args: Any, **kwargs: Any) -> Any:
            kernel: Any = fallback()
            with contextlib.suppress(LinemapError, TypeError, ValueError):  # the same parameters, if it can
                kernel = type(kernel)(self.get_params())
            return kernel.apply(*args, **kwargs)

        def apply(self, *args: Any, **kwargs: Any) -> Any:
            if state["stuck"] is not None:  # its worker is gone: never call it again
                return self._fallback(*args, **kwargs)
            t0 = clock()
            try:
                out = super().apply(*args, **kwargs)
            except WorkerError as exc:
                stuck(exc.reason)
                return self._fallback(*args, **kwargs)
            except KernelCallError as exc:
                on_failure(cls, exc.reason)
                return self._fallback(*args, **kwargs)
            except Exception as exc:
                on_failure(cls, f"{cls.name} {cls.version} raised {type(exc).__name__}: {exc}")
                return self._fallback(*args, **kwargs)
            elapsed_ms = (clock() - t0) * 1e3
            problems = check_result(cls.stage, out, _n_in(cls.stage, args, kwargs))
            if problems:
                shown = "; ".join(problems[:3])
                on_failure(cls, f"{cls.name} {cls.version} returned a bad result: {shown}"[:500])
                return self._fallback(*args, **kwargs)
            state["over"] = state["over"] + 1 if elapsed_ms > budget_ms else 0
            if state["over"] == overruns:
                on_failure(
                    cls,
                    f"{cls.name} {cls.version} took {elapsed_ms:.1f} ms, over its {budget_ms:g} ms budget "
                    f"({overruns} calls in a row)",
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
