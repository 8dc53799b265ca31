"""Control message <-> :class:`shared.pipeline.PipelineConfig` (SPEC §4, §6).

:func:`to_config` applies a message to the configuration in force: what the message names replaces the base
(a kernel element replaces that stage's kernel with exactly the parameters it gives, the rest at the kernel's
defaults; ``<noise-removal>`` replaces the whole chain; ``<schedule>`` the whole schedule); what it does not
name keeps the base's value. Every kernel is built (looked up and its parameters validated) before the new
configuration exists, so a bad message is rejected whole; the error names the element (and line) that
carried the bad value, followed by the kernel's own message. Kernel operations are not configuration and
are left to the caller (the robot agent's kernel store).

:func:`from_config` is the inverse: a message stating the whole configuration, so
``to_config(from_config(c), base) == c`` for any ``base`` when every kernel of ``c`` is in the vocabulary.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from pydantic import ValidationError

from shared.control.errors import ControlMessageError
from shared.control.model import NO_SCAN_MATCHING, ControlMessage, KernelSpec, ParamValue, ScheduleEntry
from shared.control.vocabulary import LOOP_CLOSURE, is_length_param, kernel_element, param_element
from shared.errors import KernelParameterError, UnknownKernelError
from shared.kernels import Stage
from shared.pipeline.config import SCHEDULED, KernelChoice, Mode, PipelineConfig, StageSchedule
from shared.slam.errors import LoopClosureSettingsError
from shared.slam.settings import LoopClosureSettings

__all__ = ["Checkable", "from_config", "to_config"]

#: ``checkable(stage, name, version)``: whether this process holds the parameter model of that kernel
#: (``version`` None: the version the robot resolves to). False leaves that kernel's parameters unchecked
#: here (a kernel only the robot will have: an uploaded version, validated when the robot loads it).
Checkable = Callable[[Stage, str, str | None], bool]

#: Display element of each stage's kernel container (for errors).
_STAGE_ELEMENT = {
    Stage.SEGMENTATION: "segmentation",
    Stage.NOISE_REMOVAL: "noise-removal",
    Stage.CLUSTERING: "clustering",
    Stage.STRAIGHT_LINE: "straight-line-method",
    Stage.SCAN_MATCHING: "scan-matching",
}
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
    if msg.segmentation is not None:
        updates["segmentation"] = _choice(msg.segmentation, Stage.SEGMENTATION)
    if msg.noise_removal is not None:
        updates["noise_removal"] = tuple(_choice(s, Stage.NOISE_REMOVAL) for s in msg.noise_removal)
    if msg.clustering is not None:
        updates["clustering"] = _choice(msg.clustering, Stage.CLUSTERING)
    if msg.straight_line is not None:
        updates["straight_line"] = _choice(msg.straight_line, Stage.STRAIGHT_LINE)
    if msg.scan_matching == NO_SCAN_MATCHING:
        updates["scan_matching"] = None
    elif isinstance(msg.scan_matching, KernelSpec):
        updates["scan_matching"] = _choice(msg.scan_matching, Stage.SCAN_MATCHING)
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


_KERNEL_FIELDS = ("segmentation", "noise_removal", "clustering", "straight_line", "scan_matching")


def _stand_ins(fields: dict[str, Any], left: list[KernelChoice]) -> dict[str, Any]:
    """``fields`` with every choice of ``left`` replaced by the default kernel of its stage (built in)."""
    default = PipelineConfig()
    out = dict(fields)
    for name in _KERNEL_FIELDS:
        value = out[name]
        if name == "noise_removal":
            out[name] = tuple(default.noise_removal[0] if any(c is v for v in left) else c for c in value)
        elif any(value is v for v in left):
            out[name] = getattr(default, name)
    return out


def from_config(config: PipelineConfig, seq: int | None = None) -> ControlMessage:
    """A message that states all of ``config``; :class:`ControlMessageError` if the vocabulary cannot."""
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
        segmentation=_spec(config.segmentation, Stage.SEGMENTATION),
        noise_removal=tuple(_spec(c, Stage.NOISE_REMOVAL) for c in config.noise_removal),
        clustering=_spec(config.clustering, Stage.CLUSTERING),
        straight_line=_spec(config.straight_line, Stage.STRAIGHT_LINE),
        scan_matching=(
            NO_SCAN_MATCHING
            if config.scan_matching is None
            else _spec(config.scan_matching, Stage.SCAN_MATCHING)
        ),
        schedule=tuple(schedule),
        loop_closure=KernelSpec(
            LOOP_CLOSURE.name,
            tuple((config.loop_closure or {"enabled": False}).items()),
        ),
    )


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
    if stage in (Stage.STRAIGHT_LINE, Stage.SCAN_MATCHING):
        return f"<{_STAGE_ELEMENT[stage]}>"
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
    if kernel_element(stage, choice.name) is None:
        raise ControlMessageError(
            f"kernel {choice.name!r} of stage {stage.value} has no element in the control vocabulary",
            element=f"<{_STAGE_ELEMENT[stage]}>",
        )
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
