"""Errors raised by the simulator: bad world files and impossible run settings."""

from __future__ import annotations

from pathlib import Path

from shared.errors import InvalidInputError

__all__ = ["WorldFileError"]


class WorldFileError(InvalidInputError):
    """A world file cannot be read, parsed or validated.

    ``path`` is the file; ``entry`` names the bad entry (e.g. ``walls[3]``) or is empty for whole-file
    problems. The message names both and what was expected.
    """

    def __init__(self, path: Path | str, message: str, entry: str = "") -> None:
        self.path = Path(path)
        self.entry = entry
        where = f"{self.path}: {entry}: " if entry else f"{self.path}: "
        super().__init__(where + message)
