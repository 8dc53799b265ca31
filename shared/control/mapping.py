"""Control message <-> :class:`shared.pipeline.PipelineConfig` (docs/design.md §4, §6).

:func:`to_config` applies a message to the configuration in force: what the message names replaces the base
(a kernel element replaces that stage's kernel with exactly the parameters it gives, the rest at the kernel's
defaults; ``<noise-removal>`` replaces the whole chain; ``<schedule>`` the whole schedule); what it does not
name keeps the base's value. Every kernel is built (looked up and its parameters validated) before the new
configuration exists, so a bad message is rejected whole; the error names the element (and line) that
carried the bad value, followed by the kernel's own message. Kernel operations are not configuration and
are left to the caller (the robot agent's kernel store).

:func:`from_config` is the inverse: a message stating the whole configuration, so
``to_config(from_config(c), base) == c`` for any ``base`` when every kernel of ``c`` is registered (a kernel
without a paper element is stated as ``<kernel name="..">``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from pydantic import ValidationError

from shared.control.errors import ControlMessageError
from shared.control.model import NO_SCAN_MATCHING, ControlMessage, KernelSpec, ParamValue, ScheduleEntry
from shared.control.vocabulary import (
    GENERIC_KERNEL,
    LOOP_CLOSURE,
    is_length_param,
    kernel_element,
    param_element,
)
from shared.errors import KernelParameterError, UnknownKernelError
from shared.kernels import Stage
from shared.kernels.stages import STAGES, StageSpec
from shared.pipeline.config import SCHEDULED, KernelChoice, Mode, PipelineConfig, StageSchedule
from shared.slam.errors import LoopClosureSettingsError
from shared.slam.settings import LoopClosureSettings

__all__ = ["Checkable", "from_config", "to_config"]

#: ``checkable(stage, name, version)``: whether this process holds the parameter model of that kernel
#: (``version`` None: the version the robot resolves to). False leaves that kernel's parameters unchecked
#: here (a kernel only the robot will have: an uploaded version, validated when the robot loads it).
Checkable = Callable[[Stage, str, str | None], bool]

#: PipelineConfig field -> message element (for errors).
_FIELD_ELEMENT = {
    "mode": "mode",
    "n_smax": "n-smax",
    "heading_flush_deg": "heading-flush",
    "schedule": "schedule",
    "loop_closure": "loop-closure",
}


def to_config(
    msg: ControlMessage, base: PipelineConfig, *, checkable: Checkable | None = None
) -> PipelineConfig:
    """``base`` with everything ``msg`` names replaced; raises :class:`ControlMessageError` if invalid.

    The one validation of a message's settings: the robot applies messages with it, and the server checks
    every message it queues with it (``checkable`` then says which kernels the server can build: those it
    cannot are left to the robot, and the whole configuration is validated with a built-in stand-in in
    their place; default: every kernel is built, as on the robot)."""
    left: list[KernelChoice] = []  # kernels this process cannot build (checkable said so)

    def _choice(spec: KernelSpec, stage: Stage) -> KernelChoice:
        if checkable is not None and not checkable(stage, spec.name, spec.version):
            choice = KernelChoice(name=spec.name, version=spec.version, params=spec.params_dict())
            left.append(choice)
            return choice
        return _built_choice(spec, stage)

    updates: dict[str, Any] = {}
    if msg.mode is not None:
        updates["mode"] = msg.mode
    if msg.n_smax is not None:
        updates["n_smax"] = msg.n_smax
    if msg.heading_flush_deg is not None:
        updates["heading_flush_deg"] = msg.heading_flush_deg
    for stage, spec in STAGES.items():
        given = getattr(msg, spec.field)
        if given is None:
            continue
        if spec.optional and given == NO_SCAN_MATCHING:
            updates[spec.field] = None
        elif spec.chain:
            updates[spec.field] = tuple(_choice(s, stage) for s in given)
        else:
            updates[spec.field] = _choice(given, stage)
    if msg.schedule is not None:
        updates["schedule"] = {e.stage: _stage_schedule(e) for e in msg.schedule}
    if msg.loop_closure is not None:
        updates["loop_closure"] = _loop_closure(msg.loop_closure)
    fields = {name: getattr(base, name) for name in PipelineConfig.model_fields}
    merged = {**fields, **updates}
    try:
        config = PipelineConfig.model_validate(_stand_ins(merged, left) if left else merged)
    except ValidationError as exc:
        err = exc.errors()[0]
        field = str(err["loc"][0]) if err["loc"] else ""
        element = _FIELD_ELEMENT.get(field)
        reason = f"{field or 'configuration'}: {err['msg']}"
        raise ControlMessageError(
            reason,
            element=f"<{element}>" if element else None,
            line=msg.line_of(element) if element else None,
        ) from None
    # with stand-ins validated, the real (unbuilt) choices go back in, unvalidated
    return config.model_copy(update={k: merged[k] for k in _KERNEL_FIELDS}) if left else config


_KERNEL_FIELDS = tuple(spec.field for spec in STAGES.values())


def _stand_ins(fields: dict[str, Any], left: list[KernelChoice]) -> dict[str, Any]:
    """``fields`` with every choice of ``left`` replaced by the default kernel of its stage (built in)."""
    default = PipelineConfig()
    out = dict(fields)
    for spec in STAGES.values():
        name, value = spec.field, out[spec.field]
        if spec.chain:
            first = default.choices(spec.stage)[0]
            out[name] = tuple(first if any(c is v for v in left) else c for c in value)
        elif any(value is v for v in left):
            out[name] = getattr(default, name)
    return out


def from_config(config: PipelineConfig, seq: int | None = None) -> ControlMessage:
    """A message that states all of ``config``; :class:`ControlMessageError` if a value cannot be carried."""
    schedule = []
    for stage in SCHEDULED:
        if stage in config.schedule:
            entry = config.schedule[stage]
            if entry.mode is Mode.MIXED:
                raise ControlMessageError(
                    f"stage {stage.value} is scheduled 'mixed': a stage runs online or offline",
                    element="<stage>",
                )
            schedule.append(ScheduleEntry(stage, entry.mode, entry.n_smax))
    return ControlMessage(
        seq=seq,
        mode=config.mode,
        n_smax=config.n_smax,
        heading_flush_deg=config.heading_flush_deg,
        **{spec.field: _stated(config, spec) for spec in STAGES.values()},
        schedule=tuple(schedule),
        loop_closure=KernelSpec(
            LOOP_CLOSURE.name,
            tuple((config.loop_closure or {"enabled": False}).items()),
        ),
    )


def _stated(config: PipelineConfig, spec: StageSpec) -> Any:
    """How a message states ``config``'s choice for a stage: a tuple for a chain, the "none" switch for an
    optional stage that is off, one kernel element otherwise."""
    chosen = [_spec(c, spec.stage) for c in config.choices(spec.stage)]
    if spec.chain:
        return tuple(chosen)
    if not chosen and spec.optional:
        return NO_SCAN_MATCHING
    return chosen[0]


def _built_choice(spec: KernelSpec, stage: Stage) -> KernelChoice:
    """Validate ``spec`` by building its kernel; errors name the element that carried the bad value."""
    choice = KernelChoice(name=spec.name, version=spec.version, params=spec.params_dict())
    try:
        choice.build(stage)
    except KernelParameterError as exc:
        param = exc.problems[0][0] if exc.problems else ""
        known = param in dict(spec.params)
        element = param_element(stage, spec.name, param) if known else _kernel_display(spec, stage)
        line = spec.param_line(param) if known else spec.line
        raise ControlMessageError(str(exc), element=element, line=line) from None
    except UnknownKernelError as exc:
        raise ControlMessageError(str(exc), element=_kernel_display(spec, stage), line=spec.line) from None
    return choice


def _kernel_display(spec: KernelSpec, stage: Stage) -> str:
    if kernel_element(stage, spec.name) is None:
        return f'<{GENERIC_KERNEL} name="{spec.name}">'
    if stage in (Stage.STRAIGHT_LINE, Stage.SCAN_MATCHING):
        return f"<{STAGES[stage].element}>"
    return f"<{spec.name}>"


def _loop_closure(spec: KernelSpec) -> dict[str, Any] | None:
    """The configuration's ``loop_closure`` for a ``<loop-closure>`` element (None: off); errors name the
    setting and the element's line."""
    try:
        settings = LoopClosureSettings.parse(spec.params_dict())
    except LoopClosureSettingsError as exc:
        field = exc.fields[0] if exc.fields else ""
        named = LOOP_CLOSURE.by_param(field)
        if named is not None and field in dict(spec.params):
            element, line = f"<{named.element}>", spec.param_line(field)
        elif field in dict(spec.params):
            element, line = f'<param name="{field}">', spec.param_line(field)
        else:
            element, line = "<loop-closure>", spec.line
        raise ControlMessageError(str(exc), element=element, line=line) from None
    return settings.as_dict() if settings.enabled else None


def _stage_schedule(entry: ScheduleEntry) -> StageSchedule:
    try:
        if entry.n_smax is None:
            return StageSchedule(mode=entry.mode)
        return StageSchedule(mode=entry.mode, n_smax=entry.n_smax)
    except ValidationError as exc:
        err = exc.errors()[0]
        raise ControlMessageError(
            f"stage {entry.stage.value}: {'.'.join(map(str, err['loc']))}: {err['msg']}",
            element="<stage>",
            line=entry.line,
        ) from None


def _spec(choice: KernelChoice, stage: Stage) -> KernelSpec:
    return KernelSpec(choice.name, tuple(_params(choice.name, choice.params).items()), choice.version)


def _params(kernel: str, params: Mapping[str, Any]) -> dict[str, ParamValue]:
    out: dict[str, ParamValue] = {}
    for name, value in params.items():
        if isinstance(value, list):
            value = tuple(value)
        if is_length_param(name) and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        ok = isinstance(value, bool | int | float | str) or (
            isinstance(value, tuple) and all(isinstance(v, int) and not isinstance(v, bool) for v in value)
        )
        if not ok:
            raise ControlMessageError(
                f"{kernel}.{name} = {value!r}: the control message carries numbers, text and integer lists",
                element=f'<param name="{name}">',
            )
        out[name] = value
    return out
