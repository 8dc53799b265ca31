"""Applying a control message to the running pipeline, between two steps (docs/design.md §6, §9).

The slow part (download, verification, conformance, dry run of kernels) happens before, on the network
thread (:class:`Prepared`); what runs between two steps is only registering verified classes, computing the
new configuration and building its kernels, so the swap costs milliseconds and no step is skipped. A
message that fails anywhere changes nothing: registrations are undone and the old configuration stays.

Kernel operations: ``install`` makes a version available; ``update`` makes it available and switches every
use of that kernel name in its stage to it; ``rollback`` switches every use to the given (registered) version;
``delete`` forgets a version that is not in use. Unpinned kernel choices are pinned to the version in use (or
the highest registered), so installing never changes what runs by accident.

Anti-rollback (docs/design.md §9, docs/reliability/supply-chain.md): the robot never runs a version lower than
one it has already run for the same kernel unless the operator overrides that explicitly. The agent keeps the
highest version put in force per ``(stage, name)`` (its *floor*, in the Robot DB). :func:`refuse_downgrades`
applies one rule to every way a message could put a version below its floor (``<kernel-install>``,
``<kernel-update>``, ``<kernel-rollback>``, a stage element selecting a version, and any combination in one
message): it is refused unless the same message carries ``<kernel-rollback ... below-floor="allow"/>`` to
exactly that version. That attribute is the override; the server records who queued it in its audit log
(``kernel.below_floor``). A replayed, validly signed old artifact is therefore refused in every form: a fixed
kernel ships as a new, higher version.

Fallbacks (:func:`refuse_deletions`, :func:`fallback_choice`): built-in kernels ship with the agent and are
the last fallback of every downloaded kernel, so ``<kernel-delete>`` of a built-in version is refused, and so
is deleting the last other version of a kernel in service; a kernel that fails with no version of its own
to go back to is answered by its stage's default built-in kernel, never by an error out of the step loop.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from shared.control import ControlMessage, KernelOperation, OperationKind, to_config
from shared.errors import LinemapError
from shared.kernels import REGISTRY, Kernel, Stage
from shared.kernels.stages import STAGES
from shared.kernels.versions import parse_version
from shared.pipeline import KernelChoice, PipelineConfig

__all__ = [
    "Floors",
    "Prepared",
    "apply_message",
    "choices",
    "fallback_choice",
    "is_builtin",
    "kernels_in_use",
    "kernels_run",
    "pin_versions",
    "refuse_deletions",
    "refuse_downgrades",
    "registered",
    "replace_choice",
    "retarget",
    "swap_version",
]

#: ``(stage, name) -> version``: the highest version of each kernel the robot has put in force.
Floors = Mapping[tuple[str, str], str]


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
    return [] if config is None else config.choices(stage)


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
        f" already run (rollback attack?); to go back to {version} on purpose send"
        f' <kernel-rollback stage="{stage}" name="{name}" version="{version}" below-floor="allow"/>'
        " (an operator override, recorded in the server's audit log)"
    )


def refuse_downgrades(
    msg: ControlMessage,
    floors: Floors,
    current: PipelineConfig | None = None,
    config: PipelineConfig | None = None,
) -> str | None:
    """Why ``msg`` would take a kernel below its floor, or ``None`` when it does not (docs/design.md §9).

    One rule for every path: an install, update or rollback operation naming a version below the floor, and
    (given the configuration in force, ``current``, and the one the message leads to, ``config``, versions
    pinned) every kernel choice ``config`` newly runs below its floor, is refused unless the same message
    has ``<kernel-rollback below-floor="allow">`` to exactly that ``(stage, name, version)``. A version
    already running stays allowed (it is not newly put in force). The reason names the element, the kernel,
    its version, the floor and the override. O(operations + choices).
    """
    ops = msg.operations
    allowed = {
        (op.stage.value, op.name, op.version)
        for op in ops
        if op.kind is OperationKind.ROLLBACK and op.below_floor
    }
    for op in ops:
        key = (op.stage.value, op.name, op.version)
        floor = floors.get(key[:2])
        moves = op.kind is not OperationKind.DELETE
        if moves and key not in allowed and floor is not None and _below(op.version, floor):
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


def is_builtin(cls: type[Any]) -> bool:
    """Whether kernel class ``cls`` ships with linemap (defined in :mod:`shared.kernels`), not downloaded."""
    return str(getattr(cls, "__module__", "")).startswith("shared.kernels.")


def refuse_deletions(
    deletions: Iterable[KernelOperation],
    config: PipelineConfig,
    registered: Iterable[tuple[str, str, str, bool]],
) -> str | None:
    """Why the ``<kernel-delete>`` operations ``deletions`` must not be applied with ``config`` in force,
    or ``None``. ``registered`` lists ``(stage, name, version, built_in)`` of every registered kernel.

    Refused: deleting a version in use; deleting a built-in version (the last fallback of every downloaded
    kernel; it would come back at the next start anyway); and deleting versions so that a kernel in service
    has no other version of its name left to fall back to. The reason names the kernel in service that
    depends on the deleted version. O(deletions x registered + choices).
    """
    reg, ops = list(registered), list(deletions)
    gone = {(op.stage.value, op.name, op.version) for op in ops}
    in_use = {(stage.value, c.name, c.version) for stage in Stage for c in choices(config, stage)}
    for op in ops:
        key = (op.stage.value, op.name, op.version)
        where = f"<kernel-delete> {op.stage.value}/{op.name} {op.version}"
        users = sorted(f"{n} {v}" for s, n, v in in_use if s == key[0] and n == key[1] and v != key[2])
        if key in in_use:
            return f"{where}: it is in use; select another version first"
        if any((s, n, v) == key and builtin for s, n, v, builtin in reg):
            served = f"; {', '.join(users)} in service falls back to it" if users else ""
            return (
                f"{where}: a built-in version cannot be deleted (built-in kernels are the last fallback of"
                f" every downloaded kernel{served})"
            )
        for stage, name, version in sorted(in_use):
            if (stage, name) != key[:2]:
                continue
            left = [
                v for s, n, v, _b in reg if (s, n) == (stage, name) and v != version and (s, n, v) not in gone
            ]
            if not left:
                return (
                    f"{where}: it is the last fallback of {stage}/{name} {version}, which is in service;"
                    " keep it, or select another version first"
                )
    return None


def fallback_choice(
    stage: Stage,
    name: str,
    version: str,
    prev: PipelineConfig | None,
    registered: Iterable[tuple[str, str, str, bool]],
) -> tuple[str, str] | None:
    """``(name, version)`` of the registered kernel that answers for failed kernel ``stage``/``name``
    ``version``: the version of that name that ``prev`` (the configuration it was installed over) ran,
    else a built-in version of that name, else the stage's default built-in kernel (the one a default
    configuration uses), else any built-in kernel of the stage; ``None`` only when the stage has no other
    registered kernel at all. ``registered`` as in :func:`refuse_deletions`. O(registered)."""
    reg = [(s, n, v, b) for s, n, v, b in registered if s == stage.value and (n, v) != (name, version)]
    have = {(n, v) for _s, n, v, _b in reg}
    for c in choices(prev, stage):
        if c.name == name and c.version is not None and (c.name, c.version) in have:
            return c.name, c.version
    builtins = [(n, v) for _s, n, v, b in reg if b]
    same = [(n, v) for n, v in builtins if n == name]
    if same:
        return max(same, key=lambda nv: _key(nv[1]))
    defaults = [c.name for c in choices(PipelineConfig(), stage)]
    for default in defaults:
        mine = [(n, v) for n, v in builtins if n == default]
        if mine:
            return max(mine, key=lambda nv: _key(nv[1]))
    if builtins:
        return builtins[0]
    return (reg[0][1], reg[0][2]) if reg else None


def _key(version: str) -> tuple[int, int, int]:
    try:
        return parse_version(version)
    except ValueError:
        return (-1, -1, -1)


def _replace(
    config: PipelineConfig, stage: Stage, fix: Callable[[KernelChoice], KernelChoice]
) -> PipelineConfig:
    key = STAGES[stage].field
    value = getattr(config, key)
    if value is None:
        return config
    new = tuple(fix(c) for c in value) if isinstance(value, tuple) else fix(value)
    return config.model_copy(update={key: new})


def swap_version(config: PipelineConfig, stage: Stage, name: str, old: str, new: str) -> PipelineConfig:
    """``config`` with every ``stage`` choice of kernel ``name`` at version ``old`` set to ``new`` (its
    parameters kept): how a failed kernel is taken out while later settings stay."""
    return _replace(
        config,
        stage,
        lambda c: c.model_copy(update={"version": new}) if c.name == name and c.version == old else c,
    )


def replace_choice(
    config: PipelineConfig, stage: Stage, name: str, version: str, new_name: str, new_version: str
) -> PipelineConfig:
    """``config`` with every ``stage`` choice of ``name`` at ``version`` replaced by kernel ``new_name``
    ``new_version`` with its default parameters (the old ones belong to another kernel)."""
    return _replace(
        config,
        stage,
        lambda c: (
            KernelChoice(name=new_name, version=new_version) if c.name == name and c.version == version else c
        ),
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
        why = refuse_deletions(deletions, config, registered())
        if why is not None:
            raise LinemapError(why)
        build(config)
    except Exception:
        for stage, name, version in added:
            unregister(stage, name, version)
        raise
    for op in deletions:
        unregister(op.stage.value, op.name, op.version)
    return config


def registered() -> list[tuple[str, str, str, bool]]:
    """``(stage, name, version, built_in)`` of every kernel in the process-wide registry."""
    return [(info.stage.value, info.name, info.version, is_builtin(info.cls)) for info in REGISTRY]
