"""Kernel parameter schemas declared at upload: read and checked when a kernel version is uploaded, and
used to check a control message's parameters for that kernel before the message is queued.

The server runs no uploaded code, so it cannot ask an uploaded kernel for its parameter model; the operator
declares it at upload (``linemap kernels describe FILE`` prints it: the JSON Schema of the kernel's
parameter model, as ``GET /kernels/builtin`` gives it for the built-in kernels). The robot checks the
parameters again against the code itself, so a declaration can only make the server's early check stricter
or looser, never let a bad value run. JSON Schema validation by the ``jsonschema`` library (draft 2020-12);
O(size of the schema and parameters).
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

from jsonschema import Draft202012Validator
from jsonschema.exceptions import SchemaError

from server.errors import InvalidRequestError

__all__ = ["MAX_SCHEMA_BYTES", "parameter_problems", "read_declared_schema"]

#: Largest declared parameter schema (bytes of JSON).
MAX_SCHEMA_BYTES = 64 * 1024


def read_declared_schema(text: str | None) -> dict[str, Any] | None:
    """The declared schema of an upload's ``parameters`` field (``None`` when empty); 422 naming the field
    when it is not JSON, too large, not a JSON Schema, or not one of an object of parameters."""
    if text is None or not text.strip():
        return None
    if len(text.encode("utf-8")) > MAX_SCHEMA_BYTES:
        raise InvalidRequestError(
            f"parameters: {len(text.encode('utf-8'))} bytes; at most {MAX_SCHEMA_BYTES}", field="parameters"
        )
    try:
        schema = json.loads(text)
    except ValueError as exc:
        raise InvalidRequestError(
            f"parameters: not JSON ({exc}): expected the JSON Schema `linemap kernels describe` prints",
            field="parameters",
        ) from None
    if not isinstance(schema, dict) or schema.get("type") != "object":
        raise InvalidRequestError(
            'parameters: expected a JSON Schema of an object ({"type": "object", "properties": {...}})',
            field="parameters",
        )
    try:
        Draft202012Validator.check_schema(schema)
    except SchemaError as exc:
        where = "/".join(str(p) for p in exc.path) or "the top level"
        raise InvalidRequestError(
            f"parameters: not a valid JSON Schema at {where}: {exc.message}", field="parameters"
        ) from None
    return schema


def parameter_problems(schema: Mapping[str, Any], params: Mapping[str, Any]) -> list[tuple[str, str]]:
    """``(parameter, reason)`` for every way ``params`` (SI values, as the message carries them after
    units) break ``schema``, parameters in name order; empty when they fit."""
    out: list[tuple[str, str]] = []
    for err in Draft202012Validator(schema).iter_errors(dict(params)):
        if err.validator == "additionalProperties":
            known = ", ".join(sorted(schema.get("properties", {}))) or "none"
            for name in sorted(set(params) - set(schema.get("properties", {}))):
                out.append((name, f"unknown parameter (value {params[name]!r}); expected one of: {known}"))
            continue
        name = str(err.path[0]) if err.path else ""
        out.append((name, err.message))
    return sorted(out)
