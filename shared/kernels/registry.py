"""The kernel registry: look kernels up by stage and name, list them with their parameter schemas.

Kernels register themselves with the :func:`register` class decorator when their module is imported;
``import shared.kernels`` imports all built-ins. A second kernel with the same stage, name and version is
refused with :class:`DuplicateKernelError`.
"""

from __future__ import annotations

import builtins
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any, TypeVar

from shared.errors import DuplicateKernelError, LinemapError, UnknownKernelError
from shared.kernels.base import Kernel, Stage, parse_version
from shared.kernels.params import KernelParams
from shared.protocol.patterns import KERNEL_NAME_RE

__all__ = ["REGISTRY", "KernelInfo", "KernelRegistry", "register"]

K = TypeVar("K", bound=type[Kernel[Any]])


@dataclass(frozen=True, slots=True)
class KernelInfo:
    """Catalogue entry of one registered kernel."""

    stage: Stage
    name: str
    version: str
    summary: str
    cls: type[Kernel[Any]]

    def as_dict(self) -> dict[str, Any]:
        """JSON-compatible description including the parameter JSON Schema."""
        return {
            "stage": str(self.stage),
            "name": self.name,
            "version": self.version,
            "summary": self.summary,
            "parameters": self.cls.param_schema(),
        }


class KernelRegistry:
    """Kernels by ``(stage, name)`` and version."""

    def __init__(self) -> None:
        self._kernels: dict[tuple[Stage, str], dict[tuple[int, int, int], type[Kernel[Any]]]] = {}

    def register(self, cls: K) -> K:
        """Add ``cls``; checks its declaration (stage, name, version, params) first. Returns ``cls``."""
        stage = getattr(cls, "stage", None)
        name = getattr(cls, "name", None)
        if not isinstance(stage, Stage):
            raise LinemapError(f"kernel class {cls.__name__} has stage {stage!r}: expected a Stage member")
        if not isinstance(name, str) or not KERNEL_NAME_RE.fullmatch(name):
            raise LinemapError(
                f"kernel class {cls.__name__} has name {name!r}: expected lower-case words joined by '-'"
            )
        try:
            version = parse_version(cls.version)
        except ValueError as exc:
            raise LinemapError(f"kernel {name}: {exc}") from None
        params = getattr(cls, "Params", None)
        if not (isinstance(params, type) and issubclass(params, KernelParams)):
            raise LinemapError(f"kernel {name}: Params must be a KernelParams subclass, got {params!r}")
        versions = self._kernels.setdefault((stage, name), {})
        if version in versions:
            raise DuplicateKernelError(
                f"kernel {stage}/{name}@{cls.version} is already registered"
                f" (by {versions[version].__qualname__})"
            )
        versions[version] = cls
        return cls

    def unregister(self, stage: Stage | str, name: str, version: str) -> None:
        """Remove one version (used when a hot-swapped kernel is deleted)."""
        key = (Stage(stage), name)
        versions = self._kernels.get(key, {})
        versions.pop(parse_version(version), None)
        if not versions:
            self._kernels.pop(key, None)

    def get(self, stage: Stage | str, name: str, version: str | None = None) -> type[Kernel[Any]]:
        """The kernel class for ``stage``/``name`` at ``version`` (default: the highest registered)."""
        try:
            stage = Stage(stage)
        except ValueError:
            known = ", ".join(s.value for s in Stage)
            raise UnknownKernelError(f"unknown stage {stage!r}: expected one of {known}") from None
        versions = self._kernels.get((stage, name))
        if not versions:
            known = ", ".join(sorted(n for s, n in self._kernels if s == stage)) or "none"
            raise UnknownKernelError(f"no kernel named {name!r} in stage {stage}: known kernels are {known}")
        if version is None:
            return versions[max(versions)]
        try:
            return versions[parse_version(version)]
        except (KeyError, ValueError):
            have = ", ".join(".".join(map(str, v)) for v in sorted(versions))
            raise UnknownKernelError(
                f"kernel {stage}/{name} has no version {version!r}: registered versions are {have}"
            ) from None

    def create(
        self,
        stage: Stage | str,
        name: str,
        params: Mapping[str, Any] | None = None,
        version: str | None = None,
    ) -> Kernel[Any]:
        """Instantiate a kernel with validated parameters."""
        return self.get(stage, name, version)(params)

    def __iter__(self) -> Iterator[KernelInfo]:
        order = list(Stage)
        items = sorted(self._kernels.items(), key=lambda kv: (order.index(kv[0][0]), kv[0][1]))
        for (stage, name), versions in items:
            for v in sorted(versions):
                cls = versions[v]
                summary = (cls.__doc__ or "").strip().splitlines()[0] if cls.__doc__ else ""
                yield KernelInfo(stage, name, cls.version, summary, cls)

    def list(self, stage: Stage | str | None = None) -> builtins.list[KernelInfo]:
        """All registered kernels (optionally of one stage), in stage order then by name and version."""
        want = None if stage is None else Stage(stage)
        return [info for info in self if want is None or info.stage == want]

    def describe(self) -> builtins.list[dict[str, Any]]:
        """The catalogue as JSON-compatible dicts with parameter schemas (for the dashboard and the API)."""
        return [info.as_dict() for info in self]


#: The process-wide registry the built-in kernels register into.
REGISTRY = KernelRegistry()


def register(cls: K) -> K:
    """Class decorator: add a kernel class to :data:`REGISTRY`."""
    return REGISTRY.register(cls)
