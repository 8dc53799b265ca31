"""Where the agent's scans come from: ``sim``, ``sim:WORLD_FILE``, a log file, or ``urg:DEVICE``.

Sources are plain iterators of :class:`shared.types.Scan` (with odometry); pacing is the agent's job. A
source that cannot be opened raises :class:`SourceError` naming the spec and what was expected.

A simulated robot drives its world's path once, or patrols it ``laps`` times (0: until stopped; see
:func:`shared.sim.patrol_scans`).
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

from robot_agent.errors import SourceError
from shared.errors import LinemapError
from shared.types import Scan

__all__ = ["default_rate_hz", "open_scans"]


def default_rate_hz(spec: str) -> float:
    """The pace a source runs at unless told otherwise: the URG-04LX's 10 Hz."""
    return 10.0


def open_scans(spec: str, *, seed: int = 0, laps: int = 1) -> Iterator[Scan]:
    """Scans from ``spec`` (see the module docstring)."""
    if spec.startswith("urg:"):
        raise SourceError(
            f"source {spec!r}: the URG-04LX serial driver is not part of this version yet; use 'sim', "
            "'sim:WORLD_FILE' or a log file"
        )
    if laps != 1 and not (spec == "sim" or spec.startswith("sim:")):
        raise SourceError(
            f"source {spec!r}: laps = {laps} applies to simulated sources ('sim', 'sim:WORLD') only"
        )
    if spec == "sim" or spec.startswith("sim:"):
        from shared.sim import default_world, load_world, patrol_scans, simulate_run

        try:
            world = default_world() if spec == "sim" else load_world(Path(spec[4:]))
        except LinemapError as exc:
            raise SourceError(f"source {spec!r}: {exc}") from None
        if laps == 1:
            yield from simulate_run(world, seed=seed).scans
        else:
            try:
                yield from patrol_scans(world, seed=seed, laps=laps)
            except LinemapError as exc:
                raise SourceError(f"source {spec!r}: {exc}") from None
        return
    from shared.io import open_log

    path = Path(spec)
    if not path.is_file():
        raise SourceError(
            f"source {spec!r}: no such file (expected 'sim', 'sim:WORLD_FILE', a log or 'urg:DEVICE')"
        )
    try:
        with open_log(path, None) as reader:
            yield from reader
    except LinemapError as exc:
        raise SourceError(f"source {spec!r}: {exc}") from None
