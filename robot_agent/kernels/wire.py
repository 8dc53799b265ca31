"""The message format between the agent and a kernel worker process (see docs/reliability/sandbox.md).

What a worker sends comes from untrusted code, so it is never unpickled: a message is one JSON header
frame followed by one raw frame per numpy array (length-prefixed frames over a socket pair). The
header is a tree of JSON values in which an array is ``{"__nd__": i, "dtype": "<f8", "shape": [n, 2]}``
(frame ``i``) and a dataclass is ``{"__dc__": "Segments", "f": {...}}`` with its ``__init__`` fields.
:func:`decode` accepts only the dataclasses of :data:`TYPES`, numeric and boolean dtypes, shapes that
match their frame's length, at most :data:`MAX_FRAMES` frames and :data:`MAX_MESSAGE_BYTES` in all,
and raises :class:`WireError` naming what was wrong otherwise.

Cost: one copy of each array into the pipe and one out of it (O(total bytes)); a 700-point scan and its
result travel in a few tens of microseconds.
"""

from __future__ import annotations

import dataclasses
import json
import math
import socket
import struct
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from shared.kernels.results import Clusters, Lines, Match, NoiseResult, Segments
from shared.types import Pose2D, Scan

__all__ = [
    "MAX_FRAMES",
    "MAX_FRAME_BYTES",
    "MAX_MESSAGE_BYTES",
    "TYPES",
    "WireError",
    "decode",
    "receive",
    "send",
]

#: The dataclasses that may cross the pipe, by name.
TYPES: dict[str, type[Any]] = {
    c.__name__: c for c in (Scan, Pose2D, Segments, NoiseResult, Clusters, Lines, Match)
}
#: At most this many array frames per message.
MAX_FRAMES = 64
#: At most this many bytes per frame (the JSON header included): 64 MiB.
MAX_FRAME_BYTES = 64 * 2**20
#: At most this many bytes per message, all frames together: 64 MiB (a scan's result is kilobytes).
MAX_MESSAGE_BYTES = 64 * 2**20
_KINDS = "biuf"  # bool, signed, unsigned, float
_MAX_DEPTH = 16


class WireError(Exception):
    """A message that is not of the format above (the reason is the message)."""


def _encode(value: Any, frames: list[Any], depth: int = 0) -> Any:
    if depth > _MAX_DEPTH:
        raise WireError(f"value nested deeper than {_MAX_DEPTH} levels")
    if value is None or isinstance(value, bool | int | float | str):
        return value
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        arr = np.ascontiguousarray(value)
        if arr.dtype.kind not in _KINDS:
            raise WireError(f"array of dtype {arr.dtype}: expected a numeric or boolean array")
        frames.append(arr)
        return {"__nd__": len(frames) - 1, "dtype": arr.dtype.str, "shape": list(arr.shape)}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        name = type(value).__name__
        if TYPES.get(name) is not type(value):
            raise WireError(f"a {name} cannot cross the pipe: expected one of {sorted(TYPES)}")
        fields = {
            f.name: _encode(getattr(value, f.name), frames, depth + 1)
            for f in dataclasses.fields(value)
            if f.init
        }
        return {"__dc__": name, "f": fields}
    if isinstance(value, list | tuple):
        return [_encode(v, frames, depth + 1) for v in value]
    if isinstance(value, dict):
        return {str(k): _encode(v, frames, depth + 1) for k, v in value.items()}
    raise WireError(f"a {type(value).__name__} cannot cross the pipe")


def send(sock: socket.socket, value: Any, timeout_s: float | None = None) -> None:
    """Send ``value`` (JSON values, numpy arrays and :data:`TYPES` dataclasses, nested) over ``sock``:
    ``[u32 header length][header][u64 length][bytes]...``. ``timeout_s`` bounds the whole send."""
    frames: list[Any] = []
    tree = _encode(value, frames)
    header = json.dumps({"n": len(frames), "v": tree}).encode()
    parts: list[Any] = [struct.pack("!I", len(header)), header]
    for arr in frames:
        data = memoryview(arr).cast("B") if arr.size else b""
        parts += [struct.pack("!Q", len(data)), data]
    sock.settimeout(timeout_s)
    sock.sendall(b"".join(parts))  # one write: the peer wakes up once, not once per frame


def _exact(sock: socket.socket, n: int, deadline: float | None) -> bytearray:
    if n > MAX_FRAME_BYTES:
        raise WireError(f"a frame of {n} bytes: expected at most {MAX_FRAME_BYTES}")
    buf = bytearray(n)
    view, got = memoryview(buf), 0
    while got < n:
        if deadline is not None:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError("no complete answer in time")
            sock.settimeout(left)
        else:
            sock.settimeout(None)
        k = sock.recv_into(view[got:])
        if k == 0:
            raise EOFError("the peer closed the connection")
        got += k
    return buf


def receive(sock: socket.socket, deadline: float | None = None) -> Any:
    """One message from ``sock``, decoded by :func:`decode`. ``deadline`` (``time.monotonic()``) bounds
    the whole message, however slowly it drips: ``TimeoutError`` past it; ``EOFError`` if the peer went."""
    (size,) = struct.unpack("!I", _exact(sock, 4, deadline))
    head = _exact(sock, size, deadline)
    try:
        top = json.loads(head)
        n = int(top["n"])
    except (ValueError, TypeError, KeyError, RecursionError) as exc:
        raise WireError(f"bad header: {type(exc).__name__}") from None
    if not 0 <= n <= MAX_FRAMES:
        raise WireError(f"{n} array frames: expected at most {MAX_FRAMES}")
    frames: list[bytes | bytearray] = []
    total = size
    for _ in range(n):
        (length,) = struct.unpack("!Q", _exact(sock, 8, deadline))
        total += length
        if total > MAX_MESSAGE_BYTES:
            raise WireError(f"a message of more than {MAX_MESSAGE_BYTES} bytes")
        frames.append(_exact(sock, length, deadline) if length else b"")
    try:
        return decode(top.get("v"), frames)
    except RecursionError:
        raise WireError("value nested too deeply") from None


def decode(value: Any, frames: Sequence[bytes | bytearray], depth: int = 0) -> Any:
    """The value a header tree and its frames stand for; :class:`WireError` for anything else."""
    if depth > _MAX_DEPTH:
        raise WireError(f"value nested deeper than {_MAX_DEPTH} levels")
    if value is None or isinstance(value, bool | int | float | str):
        return value
    if isinstance(value, list):
        return [decode(v, frames, depth + 1) for v in value]
    if not isinstance(value, dict):
        raise WireError(f"unexpected JSON value {type(value).__name__}")
    if "__nd__" in value:
        return _array(value, frames)
    if "__dc__" in value:
        cls = TYPES.get(str(value["__dc__"]))
        fields = value.get("f")
        if cls is None or not isinstance(fields, dict):
            raise WireError(f"unknown type {value['__dc__']!r}: expected one of {sorted(TYPES)}")
        allowed = {f.name for f in dataclasses.fields(cls) if f.init}
        if not set(fields) <= allowed:
            raise WireError(f"{cls.__name__} has no fields {sorted(set(fields) - allowed)}")
        kwargs = {k: decode(v, frames, depth + 1) for k, v in fields.items()}
        try:
            return cls(**kwargs)
        except Exception as exc:  # the class's own validation refused the values
            raise WireError(f"invalid {cls.__name__}: {type(exc).__name__}: {exc}") from None
    return {str(k): decode(v, frames, depth + 1) for k, v in value.items()}


def _array(value: dict[str, Any], frames: Sequence[bytes | bytearray]) -> np.ndarray:
    try:
        index = int(value["__nd__"])
        dtype = np.dtype(str(value["dtype"]))
        shape = tuple(int(s) for s in value["shape"])
    except (KeyError, TypeError, ValueError) as exc:
        raise WireError(f"bad array descriptor: {exc}") from None
    if not 0 <= index < len(frames):
        raise WireError(f"array frame {index} does not exist ({len(frames)} frames)")
    if dtype.kind not in _KINDS or dtype.hasobject or len(shape) > 4 or any(s < 0 for s in shape):
        raise WireError(f"array of dtype {dtype} and shape {shape}: expected a numeric array of <= 4 dims")
    data = frames[index]
    count = math.prod(shape)  # exact (Python integers): a huge shape cannot wrap around
    if count * dtype.itemsize != len(data):
        raise WireError(f"array of shape {shape} and dtype {dtype} does not fit its {len(data)} bytes")
    return np.frombuffer(data, dtype=dtype, count=count).reshape(shape)
