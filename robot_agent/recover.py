"""Start-up with a stored configuration that no longer builds (a downloaded kernel it names did not load
again): repair it stage by stage instead of dropping every tuned parameter (docs/reliability/agent.md).

For each kernel choice naming a version that is not registered, the highest registered version of the
same kernel takes its place *with the same parameters*; a kernel with no registered version at all leaves
the stage's default in its place (a noise-removal chain just loses that link). A stage whose choice still
does not build gets the default's choice for that stage. Everything else (mode, schedules, the other
stages' kernels and parameters) is kept. Pure apart from reading the kernel registry; O(stages x versions).
"""

from __future__ import annotations

import copy
from typing import Any

from shared.errors import LinemapError
from shared.kernels import REGISTRY, Stage
from shared.kernels.base import parse_version
from shared.kernels.stages import STAGES
from shared.pipeline import KernelChoice, PipelineConfig

__all__ = ["repair_config"]


def _registered(stage: Stage, name: str, version: str) -> bool:
    try:
        REGISTRY.get(stage, name, version)
    except LinemapError:
        return False
    return True


def _stand_in(stage: Stage, name: str) -> str | None:
    """The highest registered version of kernel ``name`` in ``stage``, or None."""
    versions = [i.version for i in REGISTRY.list(stage) if i.name == name]
    return max(versions, key=parse_version) if versions else None


def _builds(stage: Stage, value: Any) -> bool:
    try:
        for choice in value if isinstance(value, list) else [value]:
            if choice is not None:
                KernelChoice.model_validate(choice).build(stage)
    except (LinemapError, ValueError, TypeError):
        return False
    return True


def _fix_choice(stage: Stage, choice: Any, notes: list[str]) -> Any:
    """``choice`` (a KernelChoice dict) with its version replaced if that is not registered; None when no
    version of its kernel is registered."""
    if not isinstance(choice, dict) or not isinstance(choice.get("name"), str):
        return choice
    name, version = choice["name"], choice.get("version")
    if not isinstance(version, str) or _registered(stage, name, version):
        return choice
    stand_in = _stand_in(stage, name)
    if stand_in is None:
        notes.append(f"{stage} kernel {name} {version} is not available: that stage falls back")
        return None
    notes.append(
        f"{stage} kernel {name} {version} is not available: running {name} {stand_in} "
        "with the same parameters"
    )
    return {**choice, "version": stand_in}


def repair_config(stored: Any, defaults: PipelineConfig) -> tuple[PipelineConfig, list[str]]:
    """A valid configuration as close to ``stored`` (a PipelineConfig dict that does not validate) as the
    registered kernels allow, and notes saying what changed (empty: it could not be repaired and
    ``defaults`` is returned)."""
    if not isinstance(stored, dict):
        return defaults, []
    data = copy.deepcopy(stored)
    base = defaults.model_dump(mode="json")
    notes: list[str] = []
    for stage, spec in STAGES.items():
        field = spec.field
        value = data.get(field)
        if isinstance(value, list):
            fixed = [c for c in (_fix_choice(stage, c, notes) for c in value) if c is not None]
            data[field] = fixed or base[field]
        elif value is not None:
            fixed_one = _fix_choice(stage, value, notes)
            data[field] = base[field] if fixed_one is None else fixed_one
        if field in data and not _builds(stage, data[field]):
            notes.append(f"the stored {stage} settings do not build: that stage uses the defaults")
            data[field] = base[field]
    try:
        return PipelineConfig.parse(data), notes
    except LinemapError:
        return defaults, []
