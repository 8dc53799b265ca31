"""A pipeline configuration from a file: an XML control message (paper Listing 1, docs/design.md §6) or a
JSON or TOML file of :class:`~shared.pipeline.PipelineConfig` fields. Used by ``linemap map`` and by the
agent's ``--config``. Errors name the file and what was wrong with it."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

from shared.control.errors import ControlMessageError
from shared.control.mapping import to_config
from shared.control.parse import parse_message
from shared.errors import LinemapError
from shared.pipeline.config import PipelineConfig

__all__ = ["load_config"]


def load_config(path: Path | None) -> PipelineConfig:
    """The pipeline configuration in ``path`` (``None``: the defaults). A control message sets what it
    mentions on top of the defaults; a JSON or TOML file gives :class:`PipelineConfig` fields."""
    if path is None:
        return PipelineConfig()
    suffix = path.suffix.lower()
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise LinemapError(f"cannot read configuration {path}: {exc.strerror or exc}") from None
    if suffix == ".xml":
        try:
            return to_config(parse_message(raw), PipelineConfig())
        except ControlMessageError as exc:
            raise LinemapError(f"{path}: {exc}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise LinemapError(f"{path}: not UTF-8 text") from None
    try:
        data = tomllib.loads(text) if suffix == ".toml" else json.loads(text)
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
        raise LinemapError(f"{path}: not valid {'TOML' if suffix == '.toml' else 'JSON'}: {exc}") from None
    if not isinstance(data, dict):
        raise LinemapError(f"{path}: expected an object of configuration fields, got {type(data).__name__}")
    return PipelineConfig.parse(data)
