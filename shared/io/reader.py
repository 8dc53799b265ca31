"""What every log reader shares: :class:`LogInfo`, the :class:`LogReader` base and gzip-transparent input.

A reader streams: it holds one open text file and parses one line at a time, so memory stays O(beams)
whatever the log's length. Lines are numbered from 1 in the (decompressed) text, as an editor shows them.
"""

from __future__ import annotations

import gzip
import logging
import zlib
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType, TracebackType
from typing import ClassVar, Self, TextIO

import numpy as np

from shared.io.errors import LogError, LogFormatError, LogNotFoundError
from shared.odometry import DiffDrive
from shared.types import BeamGeometry, FloatArray, Pose2D, Scan

__all__ = ["GZIP_MAGIC", "LogInfo", "LogReader", "is_gzip", "open_text", "parse_count", "parse_floats"]

logger = logging.getLogger(__name__)

#: The first two bytes of every gzip member (RFC 1952).
GZIP_MAGIC = b"\x1f\x8b"

_EMPTY: Mapping[str, str] = MappingProxyType({})


@dataclass(frozen=True, slots=True)
class LogInfo:
    """What a log says about itself, known as soon as it is opened.

    ``format`` is the reader's name (``"carmen"``, ``"breezyslam"``); ``geometry`` the scanner's beam
    layout if known (for CARMEN: that of the first laser record; its ``rate_hz`` is nominal, not
    measured); ``laser_offset`` the scanner's pose in the robot frame (m, rad); ``robot`` the
    differential-drive model whose odometry the scans carry, if the reader integrated it itself;
    ``compressed`` whether the file is gzip; ``params`` the log's own parameters (CARMEN ``PARAM`` lines
    before the first laser record), as text.
    """

    format: str
    path: Path
    geometry: BeamGeometry | None = None
    laser_offset: Pose2D = field(default_factory=Pose2D)
    robot: DiffDrive | None = None
    compressed: bool = False
    params: Mapping[str, str] = field(default_factory=lambda: _EMPTY)


def is_gzip(path: Path) -> bool:
    """Whether ``path`` starts with the gzip magic bytes. Raises :class:`LogError` if it cannot be read."""
    try:
        with path.open("rb") as fh:
            return fh.read(2) == GZIP_MAGIC
    except FileNotFoundError as exc:
        raise LogNotFoundError(f"log file not found: {path}") from exc
    except IsADirectoryError as exc:
        raise LogError(f"{path} is a directory: expected a log file") from exc
    except OSError as exc:
        raise LogError(f"cannot open log file {path}: {exc}") from exc


def open_text(path: Path) -> tuple[TextIO, bool]:
    """Open ``path`` for reading as UTF-8 text, gunzipping on the fly if it is gzip (by content, not name).

    Returns the stream and whether it is compressed. Raises :class:`LogNotFoundError` or :class:`LogError`.
    """
    compressed = is_gzip(path)
    try:
        if compressed:
            return gzip.open(path, "rt", encoding="utf-8"), True
        return path.open("r", encoding="utf-8"), False
    except OSError as exc:  # pragma: no cover - is_gzip() just opened it
        raise LogError(f"cannot open log file {path}: {exc}") from exc


def parse_count(path: Path, line_no: int, fields: Sequence[str], index: int, what: str) -> int:
    """``fields[index]`` as a non-negative integer, else :class:`LogFormatError` naming ``what``.

    The record is named by ``fields[0]`` (a CARMEN message name).
    """
    if index >= len(fields):
        raise LogFormatError(
            path, line_no, f"{fields[0]} record is truncated: it ends before field {index} ({what})"
        )
    token = fields[index]
    try:
        value = int(token)
    except ValueError:
        value = -1
    if value < 0:
        raise LogFormatError(
            path, line_no, f"{fields[0]} field {index} ({what}) = {token!r}: expected a non-negative integer"
        )
    return value


def parse_floats(
    path: Path,
    line_no: int,
    fields: Sequence[str],
    spans: Sequence[tuple[int, int]],
    name_of: Callable[[int], str],
    record: str | None = None,
) -> FloatArray:
    """The fields in the half-open index ``spans`` as one float64 array (bulk conversion, no Python loop).

    On a non-numeric token, raises :class:`LogFormatError` naming the record (``record``, else
    ``fields[0]``), the 0-based field index, ``name_of(index)`` and the token. O(fields).
    """
    tokens: list[str] = []
    for start, stop in spans:
        tokens.extend(fields[start:stop])
    try:
        return np.array(tokens, dtype=np.float64)
    except ValueError:
        pass
    for start, stop in spans:
        for i in range(start, stop):
            try:
                float(fields[i])
            except ValueError:
                raise LogFormatError(
                    path,
                    line_no,
                    f"{record or fields[0]} field {i} ({name_of(i)}) = {fields[i]!r}: expected a number",
                ) from None
    return np.array([float(t) for t in tokens], dtype=np.float64)  # pragma: no cover - numpy stricter


class LogReader(ABC):
    """A streaming, single-pass reader of one log file: a context manager and an iterator of :class:`Scan`.

    Subclasses implement :meth:`_read_scans` over :meth:`_lines` and set ``_info``. Scans come out in
    file order, each with ``odometry`` = the robot's odometry pose at the scan. A malformed record raises
    :class:`LogFormatError` with its line number; nothing malformed is skipped silently.
    """

    format_name: ClassVar[str] = ""

    def __init__(self, path: Path | str) -> None:
        self.path = Path(path)
        self._file, self._compressed = open_text(self.path)
        self._scans: Iterator[Scan] = self._read_scans()
        self._pending: list[Scan] = []
        self._info = LogInfo(self.format_name, self.path, compressed=self._compressed)
        self.scans_read = 0
        self.lines_read = 0

    @property
    def info(self) -> LogInfo:
        """What the log says about itself (format, path, geometry, laser offset, robot model)."""
        return self._info

    def progress(self) -> float | None:
        """The share of the file read so far, in [0, 1] (bytes of the file as stored, compressed or not;
        the reader reads ahead a little); ``None`` when it cannot be told. O(1)."""
        try:
            size = self.path.stat().st_size
            raw = getattr(self._file.buffer, "fileobj", None) or self._file.buffer  # gzip: the file below
            done = raw.tell()
        except (OSError, ValueError, AttributeError):
            return None
        return min(1.0, done / size) if size > 0 else None

    def _lines(self) -> Iterator[tuple[int, str]]:
        """``(line_no, text)`` for every line, 1-based; read errors become :class:`LogFormatError`."""
        line_no = 0
        try:
            for text in self._file:
                line_no += 1
                self.lines_read = line_no
                yield line_no, text
        except (OSError, EOFError, UnicodeDecodeError, zlib.error) as exc:
            raise LogFormatError(
                self.path, line_no + 1, f"cannot read the file from here on ({type(exc).__name__}: {exc})"
            ) from exc

    @abstractmethod
    def _read_scans(self) -> Iterator[Scan]:
        """Parse the file into scans, in order (a generator over :meth:`_lines`)."""

    def _prime(self) -> Scan | None:
        """Read ahead to the first scan (kept for :meth:`__next__`), closing the file if that fails."""
        try:
            first = next(self._scans, None)
        except BaseException:
            self.close()
            raise
        if first is not None:
            self._pending.append(first)
        return first

    def __iter__(self) -> Self:
        return self

    def __next__(self) -> Scan:
        scan = self._pending.pop() if self._pending else next(self._scans)
        self.scans_read += 1
        return scan

    def close(self) -> None:
        """Close the file; iteration then stops. Idempotent."""
        self._pending.clear()
        close = getattr(self._scans, "close", None)
        if close is not None:
            close()
        self._file.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"{type(self).__name__}({str(self.path)!r}, scans_read={self.scans_read})"
