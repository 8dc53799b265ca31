"""Applying a control message to the running pipeline, between two steps (SPEC §6, §9).

The slow part (download, verification, conformance, dry run of kernels) happens before, on the network
thread (:class:`Prepared`); what runs between two steps is only registering verified classes, computing the
new configuration and building its kernels, so the swap costs milliseconds and no step is skipped. A
message that fails anywhere changes nothing: registrations are undone and the old configuration stays.

Kernel operations: ``install`` makes a version available; ``update`` makes it available and switches every
use of that kernel name in its stage to it; ``rollback`` switches every use to the given (registered) version;
``delete`` forgets a version that is not in use. Unpinned kernel choices are pinned to the version in use (or
the highest registered), so installing never changes what runs by accident.

Anti-rollback (SPEC §9): the robot never runs a version lower than one it has already run for the same
kernel unless a message says rollback. The agent keeps the highest version put in force per
``(stage, name)`` (its *floor*, in the Robot DB); :func:`refuse_downgrades` rejects an install or update below
the floor, and a configuration that would newly run a version below it, unless the same message carries a
``<kernel-rollback>`` to exactly that version (which may come with an install of it). A replayed, validly
signed old artifact is therefore refused: a fixed kernel ships as a new, higher version.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from shared.control import ControlMessage, KernelOperation, OperationKind, to_config
from shared.errors import LinemapError
from shared.kernels import REGISTRY, Kernel, Stage
from shared.kernels.versions import parse_version
from shared.pipeline import KernelChoice, PipelineConfig

__all__ = [
    "Floors",
    "Prepared",
    "apply_message",
    "choices",
    "kernels_in_use",
    "kernels_run",
    "pin_versions",
    "refuse_downgrades",
    "retarget",
    "swap_version",
]

#: ``(stage, name) -> version``: the highest version of each kernel the robot has put in force.
Floors = Mapping[tuple[str, str], str]

_FIELDS = {
    Stage.SEGMENTATION: "segmentation",
    Stage.NOISE_REMOVAL: "noise_removal",
    Stage.CLUSTERING: "clustering",
    Stage.STRAIGHT_LINE: "straight_line",
    Stage.SCAN_MATCHING: "scan_matching",
}


@dataclass
class Prepared:
    """A message made ready on the network thread: parsed, its kernels downloaded and verified.
    ``error`` set means it is rejected with that reason."""

    seq: int
    message: ControlMessage | None
    error: str | None = None
    classes: dict[tuple[str, str, str], type[Kernel[Any]]] = field(default_factory=dict)


def choices(config: PipelineConfig | None, stage: Stage) -> list[KernelChoice]:
    """The kernel choices ``config`` makes for ``stage`` (a chain for noise removal)."""
    if config is None:
        return []
    value = getattr(config, _FIELDS[stage])
    if value is None:
        return []
    return list(value) if isinstance(value, tuple) else [value]


def kernels_in_use(config: PipelineConfig) -> dict[str, str]:
    """``stage -> "name@version[, ...]"`` (versions as pinned)."""
    out = {}
    for stage in Stage:
        used = [f"{c.name}@{c.version or '?'}" for c in choices(config, stage)]
        if used:
            out[stage.value] = ", ".join(used)
    return out


def kernels_run(config: PipelineConfig) -> list[tuple[str, str, str]]:
    """``(stage, name, version)`` of every pinned kernel choice ``config`` runs (what raises the floors)."""
    return [(stage.value, c.name, c.version) for stage in Stage for c in choices(config, stage) if c.version]


def _below(version: str, floor: str | None) -> bool:
    try:
        return floor is not None and parse_version(version) < parse_version(floor)
    except ValueError:  # an unparsable version cannot be registered anyway; the registry names it
        return False


def _downgrade(where: str, stage: str, name: str, version: str, floor: str) -> str:
    return (
        f"{where} {stage}/{name} {version}: version {version} is lower than {floor}, which this robot has"
        f" already run (rollback attack?); send <kernel-rollback> to go back to {version} on purpose"
    )


def refuse_downgrades(
    msg: ControlMessage,
    floors: Floors,
    current: PipelineConfig | None = None,
    config: PipelineConfig | None = None,
) -> str | None:
    """Why ``msg`` would take a kernel below its floor, or ``None`` when it does not (SPEC §9).

    Checked: every install and update operation; and, given the configuration in force (``current``) and
    the one the message leads to (``config``, versions pinned), every kernel choice ``config`` newly runs.
    A version that a ``<kernel-rollback>`` of the same message names is allowed (explicit rollback).
    The reason names the element, the kernel, its version and the floor. O(operations + choices).
    """
    ops = msg.operations
    allowed = {(op.stage.value, op.name, op.version) for op in ops if op.kind is OperationKind.ROLLBACK}
    for op in ops:
        key = (op.stage.value, op.name, op.version)
        floor = floors.get(key[:2])
        installs = op.kind in (OperationKind.INSTALL, OperationKind.UPDATE)
        if installs and key not in allowed and floor is not None and _below(op.version, floor):
            return _downgrade(f"<kernel-{op.kind.value}>", *key, floor)
    if config is None:
        return None
    for stage in Stage:
        before = {(c.name, c.version) for c in choices(current, stage)}
        for c in choices(config, stage):
            new = (c.name, c.version) not in before and (stage.value, c.name, c.version) not in allowed
            if c.version is None or not new:
                continue
            floor = floors.get((stage.value, c.name))
            if floor is not None and _below(c.version, floor):
                return _downgrade(f"<{stage.value}>", stage.value, c.name, c.version, floor)
    return None


def _replace(
    config: PipelineConfig, stage: Stage, fix: Callable[[KernelChoice], KernelChoice]
) -> PipelineConfig:
    value = getattr(config, _FIELDS[stage])
    if value is None:
        return config
    new = tuple(fix(c) for c in value) if isinstance(value, tuple) else fix(value)
    return config.model_copy(update={_FIELDS[stage]: new})


def swap_version(config: PipelineConfig, stage: Stage, name: str, old: str, new: str) -> PipelineConfig:
    """``config`` with every ``stage`` choice of kernel ``name`` at version ``old`` set to ``new`` (its
    parameters kept): how a failed kernel is taken out while later settings stay."""
    return _replace(
        config,
        stage,
        lambda c: c.model_copy(update={"version": new}) if c.name == name and c.version == old else c,
    )


def pin_versions(config: PipelineConfig, current: PipelineConfig | None = None) -> PipelineConfig:
    """Give every unpinned choice a version: the one ``current`` runs for that name, else the highest."""
    for stage in Stage:
        running = {c.name: c.version for c in choices(current, stage)} if current is not None else {}

        def fix(
            c: KernelChoice, stage: Stage = stage, running: dict[str, str | None] = running
        ) -> KernelChoice:
            if c.version is not None:
                return c
            version = running.get(c.name) or REGISTRY.get(stage, c.name).version
            return c.model_copy(update={"version": version})

        config = _replace(config, stage, fix)
    return config


def retarget(config: PipelineConfig, stage: Stage, name: str, version: str) -> PipelineConfig:
    """Every use of ``name`` in ``stage`` switched to ``version``."""
    return _replace(
        config, stage, lambda c: c.model_copy(update={"version": version}) if c.name == name else c
    )


def apply_message(
    prepared: Prepared,
    current: PipelineConfig,
    register: Callable[[type[Kernel[Any]]], None],
    unregister: Callable[[str, str, str], None],
    build: Callable[[PipelineConfig], None],
    floors: Floors | None = None,
) -> PipelineConfig:
    """The configuration after ``prepared``, already built and put in force by ``build`` (the pipeline's
    ``reconfigure``). On any error everything is undone and a :class:`LinemapError` names the reason.
    With ``floors`` (the robot's anti-rollback floors), a message that would go below one is refused
    (:func:`refuse_downgrades`) before anything is built."""
    msg = prepared.message
    assert msg is not None and prepared.error is None
    added: list[tuple[str, str, str]] = []
    deletions: list[KernelOperation] = []
    try:
        for key, cls in prepared.classes.items():
            register(cls)
            added.append(key)
        config = to_config(msg, current)
        for op in msg.operations:
            if op.kind in (OperationKind.UPDATE, OperationKind.ROLLBACK):
                REGISTRY.get(op.stage, op.name, op.version)  # must be there: built in or installed
                config = retarget(config, op.stage, op.name, op.version)
            elif op.kind is OperationKind.DELETE:
                deletions.append(op)
        config = pin_versions(config, current)
        if floors is not None:
            why = refuse_downgrades(msg, floors, current, config)
            if why is not None:
                raise LinemapError(why)
        for op in deletions:
            if any(c.name == op.name and c.version == op.version for c in choices(config, op.stage)):
                raise LinemapError(
                    f"<kernel-delete>: {op.stage}/{op.name} {op.version} is in use; "
                    "select another version first"
                )
        build(config)
    except Exception:
        for stage, name, version in added:
            unregister(stage, name, version)
        raise
    for op in deletions:
        unregister(op.stage.value, op.name, op.version)
    return config
