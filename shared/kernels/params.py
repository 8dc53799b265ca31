"""Kernel parameters declared as data: a frozen pydantic model per kernel, with units and ranges.

A parameter is declared with :func:`param`, which records its unit and allowed range in the JSON Schema the
dashboard reads. :func:`validate_params` turns pydantic's errors into one :class:`KernelParameterError` whose
message names each bad parameter, the bad value and the allowed range.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, TypeVar

import annotated_types
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from shared.errors import KernelParameterError

__all__ = ["KernelParams", "allowed_range", "param", "validate_params"]

P = TypeVar("P", bound="KernelParams")


class KernelParams(BaseModel):
    """Base of every kernel's parameter model: immutable, unknown names rejected, defaults validated."""

    model_config = ConfigDict(frozen=True, extra="forbid", validate_default=True, strict=False)


def param(
    default: Any,
    *,
    description: str,
    unit: str | None = None,
    ge: float | None = None,
    gt: float | None = None,
    le: float | None = None,
    lt: float | None = None,
    paper: str | None = None,
    choices: list[str] | None = None,
) -> Any:
    """Declare one kernel parameter: default, unit (``"m"``, ``"rad"``, ``"deg"``, ``None``), range, doc.

    ``choices`` lists the accepted spellings of a text parameter (published as the schema's ``enum``, so a
    dashboard can offer them; the model's own validator still does the checking).
    """
    extra: dict[str, Any] = {}
    if unit is not None:
        extra["unit"] = unit
    if paper is not None:
        extra["paper"] = paper
    if choices is not None:
        extra["enum"] = list(choices)
    return Field(
        default, description=description, ge=ge, gt=gt, le=le, lt=lt, json_schema_extra=extra or None
    )


def allowed_range(model: type[KernelParams], name: str) -> str | None:
    """Human-readable allowed range of parameter ``name`` (e.g. ``"0 < epsilon_m <= 10 m"``), if bounded."""
    field = model.model_fields.get(name)
    if field is None:
        return None
    low: tuple[str, object] | None = None
    high: tuple[str, object] | None = None
    for meta in field.metadata:
        if isinstance(meta, annotated_types.Ge):
            low = ("<=", meta.ge)
        elif isinstance(meta, annotated_types.Gt):
            low = ("<", meta.gt)
        elif isinstance(meta, annotated_types.Le):
            high = ("<=", meta.le)
        elif isinstance(meta, annotated_types.Lt):
            high = ("<", meta.lt)
    unit = ""
    extra = field.json_schema_extra
    if isinstance(extra, dict) and isinstance(extra.get("unit"), str):
        unit = f" {extra['unit']}"
    if low is not None and high is not None:
        return f"{low[1]} {low[0]} {name} {high[0]} {high[1]}{unit}"
    if low is not None:
        return f"{name} {'>=' if low[0] == '<=' else '>'} {low[1]}{unit}"
    if high is not None:
        return f"{name} {high[0]} {high[1]}{unit}"
    return None


def validate_params(kernel: str, model: type[P], values: P | Mapping[str, Any] | None) -> P:
    """Validate ``values`` against ``model``; raise :class:`KernelParameterError` naming every problem."""
    if isinstance(values, model):
        return values
    if values is None:
        values = {}
    if isinstance(values, BaseModel):
        values = values.model_dump()
    if not isinstance(values, Mapping):
        raise KernelParameterError(
            kernel,
            [("<params>", f"got {type(values).__name__}: expected a mapping of parameter names to values")],
        )
    try:
        return model.model_validate(dict(values))
    except ValidationError as exc:
        problems: list[tuple[str, str]] = []
        for err in exc.errors():
            name = ".".join(str(part) for part in err["loc"]) or "<params>"
            if err["type"] == "extra_forbidden":
                known = ", ".join(sorted(model.model_fields))
                problems.append(
                    (name, f"unknown parameter (value {err['input']!r}); expected one of: {known}")
                )
                continue
            text = f"{err['input']!r} is invalid: {err['msg']}"
            rng = allowed_range(model, str(err["loc"][0])) if err["loc"] else None
            if rng is not None:
                text += f"; allowed range {rng}"
            problems.append((name, text))
        raise KernelParameterError(kernel, problems) from None
