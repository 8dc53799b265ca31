"""Open any supported laser log by name or content: :func:`open_log`.

Formats: ``"carmen"`` (:class:`shared.io.carmen.CarmenReader`; suffixes ``.clf``, ``.log``) and
``"breezyslam"`` (:class:`shared.io.breezyslam.BreezySlamReader`; suffix ``.dat``), each optionally
``.gz``, and ``"rosbag"`` (:class:`shared.io.rosbag.RosbagReader`): a ROS 1 ``.bag``, a rosbag2 folder
(``metadata.yaml`` beside ``.db3`` or ``.mcap`` files) or a bare ``.db3`` / ``.mcap`` file. Compression is
detected from the file's magic bytes, so a gzip file without ``.gz`` also works. Another suffix is settled
by the content of the first lines: a CARMEN message name (upper-case word) or ``#`` comment means CARMEN, a
line of >= 706 numbers means BreezySLAM; a ROS bag's magic bytes get an error asking for its proper suffix
(the bag libraries pick the storage by suffix).
"""

from __future__ import annotations

import logging
import re
import zlib
from pathlib import Path

from shared.io.breezyslam import FIRST_RANGE_FIELD, BreezySlamReader
from shared.io.carmen import CarmenReader
from shared.io.errors import LogError, LogNotFoundError, UnknownLogFormatError
from shared.io.reader import LogReader, open_text
from shared.io.rosbag import RosbagReader
from shared.types import URG04LX

__all__ = ["FORMATS", "SUFFIXES", "detect_format", "open_log"]

logger = logging.getLogger(__name__)

#: Reader class per format name.
FORMATS: dict[str, type[LogReader]] = {
    "carmen": CarmenReader,
    "breezyslam": BreezySlamReader,
    "rosbag": RosbagReader,
}
#: Format per file suffix (after removing a trailing ``.gz``).
SUFFIXES: dict[str, str] = {
    ".clf": "carmen",
    ".log": "carmen",
    ".dat": "breezyslam",
    ".bag": "rosbag",
    ".db3": "rosbag",
    ".mcap": "rosbag",
}
#: Leading bytes of the binary bag containers, and the suffix each needs.
_BAG_MAGIC: tuple[tuple[bytes, str, str], ...] = (
    (b"#ROSBAG V2.0", "ROS 1 bag", ".bag"),
    (b"\x89MCAP", "MCAP file", ".mcap"),
    (b"SQLite format 3\x00", "SQLite database", ".db3"),
)

_CARMEN_NAME = re.compile(r"[A-Z][A-Z0-9_\-]*\Z")
_SNIFF_LINES = 64


def _check_not_a_bag(path: Path) -> None:
    """Raise :class:`UnknownLogFormatError` if ``path`` is a ROS bag container under a foreign suffix."""
    try:
        with path.open("rb") as fh:
            head = fh.read(16)
    except OSError:
        return  # open_text() below reports it
    for magic, what, suffix in _BAG_MAGIC:
        if head.startswith(magic):
            raise UnknownLogFormatError(
                f"{path}: holds a {what} but is named {path.name!r}: rename it to end in {suffix} "
                "(ROS bags are read by suffix)"
            )


def _sniff(path: Path) -> str:
    """The format from the first non-blank lines of ``path``'s text. O(first lines)."""
    _check_not_a_bag(path)
    stream, _ = open_text(path)
    seen = 0
    try:
        with stream:
            for text in stream:
                fields = text.split()
                if not fields:
                    continue
                seen += 1
                if fields[0].startswith("#") or _CARMEN_NAME.match(fields[0]):
                    return "carmen"
                if len(fields) > FIRST_RANGE_FIELD + URG04LX.beam_count - 1:
                    try:
                        [float(t) for t in fields[: FIRST_RANGE_FIELD + 4]]
                    except ValueError:
                        break
                    return "breezyslam"
                if seen >= _SNIFF_LINES:
                    break
    except (OSError, EOFError, UnicodeDecodeError, zlib.error) as exc:
        raise UnknownLogFormatError(f"{path}: cannot read it as text to tell its format ({exc})") from exc
    raise UnknownLogFormatError(
        f"{path}: cannot tell the log format from its name or first lines: expected a CARMEN log "
        f"({', '.join(s for s, f in SUFFIXES.items() if f == 'carmen')}) or a BreezySLAM .dat log, "
        "optionally .gz, or a ROS bag (.bag, .db3, .mcap, or a rosbag2 folder)"
    )


def detect_format(path: Path | str) -> str:
    """The format name of ``path``: a folder with ``metadata.yaml`` is a rosbag2 bag; a file goes by suffix
    (``.clf``/``.log``/``.dat``, optionally ``.gz``; ``.bag``/``.db3``/``.mcap``), else by content.

    Raises :class:`UnknownLogFormatError`, :class:`LogError` for a folder that is not a rosbag2 bag, or
    :class:`LogNotFoundError` if the file is missing.
    """
    path = Path(path)
    if path.is_dir():
        if (path / "metadata.yaml").is_file():
            return "rosbag"
        raise LogError(
            f"{path} is a directory without metadata.yaml: expected a log file or a rosbag2 folder"
        )
    suffixes = [s.lower() for s in path.suffixes]
    if suffixes and suffixes[-1] == ".gz":
        suffixes.pop()
    if suffixes and suffixes[-1] in SUFFIXES:
        return SUFFIXES[suffixes[-1]]
    return _sniff(path)


def open_log(
    path: Path | str,
    format: str | None = None,
    *,
    scan_topic: str | None = None,
    odom_topic: str | None = None,
) -> LogReader:
    """Open a laser log for streaming: a context manager and iterator of :class:`shared.types.Scan`.

    ``format`` (``"carmen"``, ``"breezyslam"``, ``"rosbag"``, case-insensitive) skips detection. ``.info``
    tells the format, geometry, laser offset and robot model. ``scan_topic`` / ``odom_topic`` choose the
    topics of a ROS bag (see :class:`~shared.io.rosbag.RosbagReader`). Raises :class:`LogNotFoundError`,
    :class:`UnknownLogFormatError`, :class:`LogError` (for a bag: :class:`RosbagError`,
    :class:`RosbagTopicError`), or :class:`LogFormatError` (with the line number) for a malformed record
    met while reading.
    """
    path = Path(path)
    if not path.exists():
        raise LogNotFoundError(f"log file not found: {path}")
    if format is None:
        name = detect_format(path)
    else:
        name = format.strip().lower()
        if name not in FORMATS:
            raise UnknownLogFormatError(
                f"log format {format!r}: expected one of {', '.join(sorted(FORMATS))}"
            )
    if name == "rosbag":
        reader: LogReader = RosbagReader(path, scan_topic=scan_topic, odom_topic=odom_topic)
    else:
        if scan_topic is not None or odom_topic is not None:
            raise LogError(f"{path}: scan_topic / odom_topic apply to ROS bags only, not to a {name} log")
        if path.is_dir():
            raise LogError(f"{path} is a directory: expected a log file")
        reader = FORMATS[name](path)
    logger.debug("opened %s as %s", path, name)
    return reader
