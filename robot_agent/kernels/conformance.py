"""The conformance battery every kernel passes
(:func:`shared.kernels.conformance.check_kernel`), as a refusal the server is told.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from robot_agent.errors import KernelRejected
from shared.kernels import Kernel
from shared.kernels.conformance import check_kernel

__all__ = ["check_conformance"]


def _ident(cls: type[Any]) -> str:
    return f"{getattr(cls, 'stage', '?')}/{getattr(cls, 'name', cls.__name__)}@{getattr(cls, 'version', '?')}"


def check_conformance(cls: type[Kernel[Any]], params: Mapping[str, Any] | None = None) -> None:
    """Run :func:`shared.kernels.conformance.check_kernel`; :class:`KernelRejected` listing the problems.

    The reason names at most 10 problems (and how many more there were). About 12 ``apply`` calls on at
    most 1000 points, in the calling process.
    """
    problems = check_kernel(cls, params)
    if problems:
        shown = "; ".join(problems[:10])
        more = f"; and {len(problems) - 10} more" if len(problems) > 10 else ""
        n = len(problems)
        raise KernelRejected(
            f"conformance failed for {_ident(cls)} ({n} problem{'s' if n > 1 else ''}): {shown}{more}"
        )
