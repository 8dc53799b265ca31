"""One ROS bag opened with ``rosbags`` (no ROS): a ROS 1 ``.bag``, a rosbag2 folder (SQLite3 or MCAP
storage) or a bare ``.db3`` / ``.mcap`` file, read message by message with the library's failures turned
into :class:`~shared.io.errors.RosbagError` / :class:`~shared.io.errors.RosbagMessageError` naming the bag,
the topic and the message number.

What the messages mean is :class:`shared.io.rosbag.RosbagReader`'s business; this module only opens,
lists topics and connections, deserialises and closes. Times are integer nanoseconds. Memory: O(1) per
message streamed.
"""

from __future__ import annotations

import logging
from collections.abc import Generator, Sequence
from pathlib import Path
from typing import Any

from rosbags.highlevel import AnyReader
from rosbags.interfaces import Connection
from rosbags.rosbag2 import Reader as Rosbag2Reader
from rosbags.typesys import Stores, get_typestore

from shared.io.errors import RosbagError, RosbagMessageError

__all__ = ["BagFile", "describe"]

logger = logging.getLogger(__name__)


def describe(exc: BaseException) -> str:
    """The library's message, with the exception's name unless it is one of rosbags' wrappers."""
    text = " ".join(str(a) for a in exc.args) or str(exc)
    name = type(exc).__name__
    if name in ("AnyReaderError", "ReaderError"):
        return text or name
    return f"{name}: {text}" if text else name


class BagFile:
    """The bag at ``path`` (an existing file or folder), open; ``ros1``: a ROS 1 ``.bag`` file (read with
    its own message definitions, else the ROS 2 Humble type store). Raises :class:`RosbagError` when it
    cannot be opened. :meth:`close` is idempotent."""

    def __init__(self, path: Path, *, ros1: bool) -> None:
        self.path = path
        self.ros1 = ros1
        self._open = False
        if path.is_dir() and not (path / "metadata.yaml").is_file():
            raise RosbagError(f"{path} is a directory without metadata.yaml: expected a rosbag2 folder")
        if not path.is_dir() and path.suffix not in (".bag", ".db3", ".mcap"):
            raise RosbagError(
                f"{path}: suffix {path.suffix!r}: a ROS bag file must end in .bag, .db3 or .mcap"
            )
        typestore = None if ros1 else get_typestore(Stores.ROS2_HUMBLE)
        try:
            bag = AnyReader([path], default_typestore=typestore)
            bag.open()
        except Exception as exc:
            raise RosbagError(
                f"{path.name}: cannot open it as a ROS bag: {describe(exc)} (truncated, corrupt, or "
                "not a bag?)"
            ) from exc
        self._open = True
        self._bag = bag

    @property
    def topics(self) -> dict[str, str]:
        """Topic name -> message type (``"(mixed types)"`` for a topic with several)."""
        return {name: info.msgtype or "(mixed types)" for name, info in self._bag.topics.items()}

    @property
    def duration_ns(self) -> int:
        """The bag's time span (ns)."""
        return int(self._bag.duration)

    def connections(self, topic: str) -> list[Connection]:
        """The connections of ``topic``."""
        return [c for c in self._bag.connections if c.topic == topic]

    def messages(self, conns: Sequence[Connection]) -> Generator[tuple[Connection, int, Any], None, None]:
        """``(connection, number on its topic, message)`` in bag order; read errors become RosbagError."""
        counts: dict[str, int] = {}
        gen = self._bag.messages(connections=conns)
        try:
            while True:
                try:
                    item = next(gen, None)
                except Exception as exc:
                    done = sum(counts.values())
                    raise RosbagError(
                        f"{self.path.name}: cannot read the bag after {done} messages "
                        f"({describe(exc)}): is it truncated or corrupt?"
                    ) from exc
                if item is None:
                    return
                conn, _, raw = item
                n = counts[conn.topic] = counts.get(conn.topic, 0) + 1
                try:
                    msg = self._bag.deserialize(raw, conn.msgtype)
                except Exception as exc:
                    raise RosbagMessageError(
                        f"{self.path.name}: {conn.topic} message {n} ({conn.msgtype}) cannot be decoded "
                        f"({describe(exc)})"
                    ) from exc
                yield conn, n, msg
        finally:
            gen.close()

    def first(self, conns: Sequence[Connection]) -> Any:
        """The first message on ``conns`` (or ``None``)."""
        gen = self.messages(conns)
        try:
            item = next(gen, None)
        finally:
            gen.close()
        return None if item is None else item[2]

    def storage(self) -> str:
        """``"rosbag1"``, ``"mcap"`` or ``"sqlite3"``."""
        if self.ros1:
            return "rosbag1"
        files = [self.path] if self.path.is_file() else sorted(self.path.iterdir())
        return "mcap" if any(f.suffix == ".mcap" for f in files) else "sqlite3"

    def is_compressed(self) -> bool:
        """Whether a rosbag2 reader of it decompresses."""
        readers = self._bag.readers
        return any(isinstance(r, Rosbag2Reader) and r.compression_mode for r in readers)

    def close(self) -> None:
        """Close the bag. Idempotent."""
        if self._open:
            self._open = False
            try:
                self._bag.close()
            except Exception as exc:  # pragma: no cover - closing files rarely fails
                logger.debug("%s: closing the bag failed: %s", self.path.name, exc)
