"""Open any supported laser log by name or content: :func:`open_log`.

Formats: ``"carmen"`` (:class:`shared.io.carmen.CarmenReader`; suffixes ``.clf``, ``.log``) and
``"breezyslam"`` (:class:`shared.io.breezyslam.BreezySlamReader`; suffix ``.dat``), each optionally
``.gz``. Compression is detected from the file's magic bytes, so a gzip file without ``.gz`` also works.
Another suffix is settled by the content of the first lines: a CARMEN message name (upper-case word) or
``#`` comment means CARMEN, a line of >= 706 numbers means BreezySLAM.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

from shared.io.breezyslam import FIRST_RANGE_FIELD, BreezySlamReader
from shared.io.carmen import CarmenReader
from shared.io.errors import LogError, UnknownLogFormatError
from shared.io.reader import LogReader, open_text
from shared.types import URG04LX

__all__ = ["FORMATS", "SUFFIXES", "detect_format", "open_log"]

logger = logging.getLogger(__name__)

#: Reader class per format name.
FORMATS: dict[str, type[LogReader]] = {"carmen": CarmenReader, "breezyslam": BreezySlamReader}
#: Format per file suffix (after removing a trailing ``.gz``).
SUFFIXES: dict[str, str] = {".clf": "carmen", ".log": "carmen", ".dat": "breezyslam"}

_CARMEN_NAME = re.compile(r"[A-Z][A-Z0-9_\-]*\Z")
_SNIFF_LINES = 64


def _sniff(path: Path) -> str:
    """The format from the first non-blank lines of ``path``'s text. O(first lines)."""
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
    except (OSError, EOFError, UnicodeDecodeError) as exc:
        raise UnknownLogFormatError(f"{path}: cannot read it as text to tell its format ({exc})") from exc
    raise UnknownLogFormatError(
        f"{path}: cannot tell the log format from its name or first lines: expected a CARMEN log "
        f"({', '.join(s for s, f in SUFFIXES.items() if f == 'carmen')}) or a BreezySLAM .dat log, "
        "optionally .gz"
    )


def detect_format(path: Path | str) -> str:
    """The format name of ``path``: by suffix (``.clf``/``.log``/``.dat``, optionally ``.gz``), else content.

    Raises :class:`UnknownLogFormatError`, or :class:`LogNotFoundError` if the file is missing.
    """
    path = Path(path)
    suffixes = [s.lower() for s in path.suffixes]
    if suffixes and suffixes[-1] == ".gz":
        suffixes.pop()
    if suffixes and suffixes[-1] in SUFFIXES:
        return SUFFIXES[suffixes[-1]]
    return _sniff(path)


def open_log(path: Path | str, format: str | None = None) -> LogReader:
    """Open a laser log for streaming: a context manager and iterator of :class:`shared.types.Scan`.

    ``format`` (``"carmen"``, ``"breezyslam"``, case-insensitive) skips detection. ``.info`` tells the
    format, geometry, laser offset and robot model. Raises :class:`LogNotFoundError`,
    :class:`UnknownLogFormatError`, :class:`LogError`, or :class:`LogFormatError` (with the line number)
    for a malformed record met while reading.
    """
    path = Path(path)
    if format is None:
        name = detect_format(path)
    else:
        name = format.strip().lower()
        if name not in FORMATS:
            raise UnknownLogFormatError(
                f"log format {format!r}: expected one of {', '.join(sorted(FORMATS))}"
            )
    if path.is_dir():
        raise LogError(f"{path} is a directory: expected a log file")
    reader = FORMATS[name](path)
    logger.debug("opened %s as %s", path, name)
    return reader
