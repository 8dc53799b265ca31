"""The XML control message from server to robot (docs/design.md §6, the paper's Listing 1): model, parser,
builder, XSD and the mapping onto :class:`shared.pipeline.PipelineConfig`::

    msg = parse_message(xml_bytes)             # hardened; ControlMessageError names element and line
    config = to_config(msg, current_config)    # validated whole; unmentioned settings kept
    xml_bytes = build_message(from_config(config, seq=7))
"""

from shared.control.build import build_message, xsd_schema, xsd_text
from shared.control.errors import ControlMessageError
from shared.control.files import load_config
from shared.control.mapping import from_config, to_config
from shared.control.model import (
    NO_SCAN_MATCHING,
    ControlMessage,
    KernelOperation,
    KernelSpec,
    OperationKind,
    ParamValue,
    ScheduleEntry,
)
from shared.control.parse import MAX_MESSAGE_BYTES, parse_message

__all__ = [
    "MAX_MESSAGE_BYTES",
    "NO_SCAN_MATCHING",
    "ControlMessage",
    "ControlMessageError",
    "KernelOperation",
    "KernelSpec",
    "OperationKind",
    "ParamValue",
    "ScheduleEntry",
    "build_message",
    "from_config",
    "load_config",
    "parse_message",
    "to_config",
    "xsd_schema",
    "xsd_text",
]
