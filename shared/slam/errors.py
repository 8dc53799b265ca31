"""Errors of the pose-graph package: one root, :class:`SlamError`, under
:class:`shared.errors.LinemapError`."""

from __future__ import annotations

from shared.errors import LinemapError

__all__ = ["LoopClosureSettingsError", "OptimisationError", "SlamError"]


class SlamError(LinemapError):
    """Root of the errors :mod:`shared.slam` raises on purpose."""


class LoopClosureSettingsError(SlamError, ValueError):
    """A loop-closure setting is out of its range; the message names it, its value and what is allowed;
    ``fields`` lists the settings at fault (first first)."""

    def __init__(self, message: str, fields: tuple[str, ...] = ()) -> None:
        super().__init__(message)
        self.fields = fields


class OptimisationError(SlamError):
    """The pose-graph optimiser failed (gtsam raised); the graph before the update stays in force."""
