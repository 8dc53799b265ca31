"""Atomic file output: write a temporary file beside the target, flush it to disk, then rename over it.

A reader never sees a half-written map: it sees the old file or the new one. O(size of the data).
"""

from __future__ import annotations

import contextlib
import logging
import os
import stat
import tempfile
from pathlib import Path

from shared.export.errors import ExportError, ExportIOError

__all__ = ["atomic_write_bytes", "atomic_write_text", "read_text"]

_log = logging.getLogger(__name__)
_DEFAULT_MODE = 0o644


def _describe(exc: OSError) -> str:
    return exc.strerror or str(exc)


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (temp file in the same folder + ``os.replace``).

    The file keeps the mode of the file it replaces, else gets 0644. The folder must exist. Raises
    :class:`ExportIOError` naming the file when anything fails; the temporary file is removed then.
    """
    target = Path(path)
    try:
        mode = stat.S_IMODE(target.stat().st_mode)
    except OSError:
        mode = _DEFAULT_MODE
    try:
        fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    except OSError as exc:
        raise ExportIOError(f"cannot write {target}: {_describe(exc)}") from exc
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp_name, mode)
        os.replace(tmp_name, target)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp_name)
        if isinstance(exc, OSError):
            raise ExportIOError(f"cannot write {target}: {_describe(exc)}") from exc
        raise
    _log.debug("wrote %s (%d bytes)", target, len(data))


def atomic_write_text(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` as UTF-8 (no BOM) to ``path`` atomically; see :func:`atomic_write_bytes`."""
    atomic_write_bytes(path, text.encode("utf-8"))


def read_text(path: str | os.PathLike[str], format_error: type[ExportError]) -> str:
    """Read a UTF-8 text file (a leading BOM is dropped).

    Raises :class:`ExportIOError` naming the file when it cannot be read, ``format_error`` when it is not
    UTF-8. O(file size).
    """
    source = Path(path)
    try:
        return source.read_text(encoding="utf-8-sig")
    except OSError as exc:
        raise ExportIOError(f"cannot read {source}: {_describe(exc)}") from exc
    except UnicodeDecodeError as exc:
        raise format_error(f"{source}: byte {exc.start} is not UTF-8: expected UTF-8 text") from exc
