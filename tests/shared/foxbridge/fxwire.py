"""Decoding Foxglove messages the way a Foxglove client does: with the protobuf schema (a serialized
FileDescriptorSet) that names the message type, through the ``protobuf`` package. Shared by the
conversion tests and the live WebSocket test."""

from __future__ import annotations

import math
from functools import cache
from typing import Any, cast

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from google.protobuf.message import Message

__all__ = ["decode", "decode_with", "yaw_of"]


@cache
def _message_class(schema_name: str, schema: bytes) -> type[Message]:
    files = descriptor_pb2.FileDescriptorSet.FromString(schema)
    pool = descriptor_pool.DescriptorPool()
    pending = list(files.file)
    added: set[str] = set()
    while pending:  # add each file after the files it imports
        ready = [f for f in pending if set(f.dependency) <= added]
        assert ready, f"unresolvable imports in the schema of {schema_name}"
        for f in ready:
            pool.Add(f)
            added.add(f.name)
            pending.remove(f)
    return cast(type[Message], message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name)))


def decode_with(schema_name: str, schema: bytes, data: bytes) -> Any:
    """The message ``data`` of type ``schema_name`` (e.g. ``foxglove.SceneUpdate``)."""
    return _message_class(schema_name, schema).FromString(data)


def decode(message: Any) -> Any:
    """A foxglove-sdk message object, encoded and decoded again with its own schema."""
    schema = type(message).get_schema()
    assert schema.encoding == "protobuf"
    return decode_with(schema.name, bytes(schema.data), message.encode())


def yaw_of(q: Any) -> float:
    """The rotation about z (rad, in (-pi, pi]) of a quaternion message with x = y = 0."""
    return math.atan2(2.0 * q.w * q.z, 1.0 - 2.0 * q.z * q.z)
