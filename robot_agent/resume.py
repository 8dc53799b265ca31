"""A restarted agent goes on with the same map at the same pose (docs/reliability/agent.md, "Restarts").

Each step's record (:meth:`robot_agent.store.RobotDB.record_step`) carries, in the same transaction, the
step's scan for the **scan journal** and, every ``every_steps`` steps or ``every_s`` seconds (and at the
first step after a start, and after the configuration changed), the pipeline's **mapping state**
(:meth:`shared.pipeline.Pipeline.state`, :meth:`shared.slam.OnlineGraphMapper.state`), which drops the
journal up to it. On a start, :meth:`Checkpoints.resume` restores that state and re-steps the journaled scans
without recording them again: the pipeline is then where it was after the last recorded step, whatever the
source (a live sensor's scans cannot be read again; the journal has them). The state is copied in the
step; its bytes (the larger part of the cost) are made on a background thread and recorded with a later
step, whose journal keeps the scans in between.

A state that does not load (another format version, damaged bytes, a journal with a gap) is an error in
the log and in the status' ``last_error``; the agent then starts a new map over the old one: its first
version removes the walls recorded before, so the two never mix. So does a Robot DB written before states
were kept. Cost: a scan's bytes per step (about 6 kB, tens of microseconds); a state every few seconds
(O(map + trajectory): about 20 ms and 250 kB after 300 steps of the simulated world).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from robot_agent.journal import scan_from_bytes, scan_to_bytes
from robot_agent.store import RobotDB, SavedState
from shared.errors import LinemapError, StateError
from shared.pipeline import MapperState
from shared.types import Pose2D, Scan

if TYPE_CHECKING:
    from robot_agent.mapping import PipelineSlot, RecentScans

__all__ = ["Checkpoints", "Continuation", "Resumed"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class Continuation:
    """A map taken over from the server (:mod:`robot_agent.continuemap`) that the pipeline has not
    started from yet: its last scan's stamp (s) and pose (world frame)."""

    stamp_s: float
    pose: Pose2D


@dataclass(frozen=True, slots=True)
class Resumed:
    """Where mapping goes on: the wall id offset, the walls recorded so far by id (``(x0, y0, x1, y1)``,
    what the next step's change is taken against), the scans re-stepped, the problem when a new map had to
    start (None: resumed, or a new Robot DB), and a map taken over from the server to start from."""

    id_offset: int
    walls: dict[int, tuple[float, ...]]
    replayed: int
    problem: str | None
    continued: Continuation | None = None


class Checkpoints:
    """When to save the mapping state and how to resume from it, over ``db``. ``clock``: monotonic s;
    ``background``: a state's bytes are made on a thread of their own (else in the step)."""

    def __init__(
        self,
        db: RobotDB,
        every_steps: int = 50,
        every_s: float = 5.0,
        clock: Callable[[], float] = time.monotonic,
        *,
        background: bool = True,
    ) -> None:
        self.db = db
        self._executor = ThreadPoolExecutor(1, "mapping-state") if background else None
        self._pending: Future[SavedState] | None = None
        self.every_steps, self.every_s, self._clock = every_steps, every_s, clock
        self._since = 0
        self._saved_at: float | None = None  # None: not saved since this start (the next step saves)
        self._config: Any = None

    def resume(self, slot: PipelineSlot, recent: RecentScans) -> Resumed:
        """Restore the saved state into ``slot``'s pipeline (not stepped yet) and re-step the journal; on
        any problem, a new map (``slot`` restarted) over the recorded one. O(state + journal)."""
        version = int(self.db.get("map_version", 0) or 0)
        walls = {int(w[0]): tuple(w[1:]) for w in self.db.walls()}
        saved = self.db.saved_state()
        if saved is None and version == 0:
            return Resumed(0, {}, 0, None)
        continued = self.db.continued_map()
        if saved is None and continued is not None and int(continued["version"]) == version:
            # taken over from the server and not stepped since: the pipeline starts from its walls
            x, y, th = (float(v) for v in continued["pose"])
            return Resumed(0, walls, 0, None, Continuation(float(continued["stamp_s"]), Pose2D(x, y, th)))
        if saved is None:
            problem = (
                f"the Robot DB holds map version {version} but no mapping state (written before states "
                "were kept)"
            )
        else:
            try:
                replayed = self._restore(slot, recent, saved, version)
            except LinemapError as exc:
                problem = f"the stored mapping state of version {saved.version} did not load: {exc}"
                config = slot.config
                assert config is not None
                slot.close()
                slot.start(config)
                self.db.forget_state()
            else:
                log.info(
                    "resumed the map at version %d: state of version %d and %d journaled scans re-stepped",
                    version,
                    saved.version,
                    replayed,
                )
                return Resumed(saved.id_offset, walls, replayed, None)
        offset = max(walls, default=-1) + 1
        problem += (
            f"; a new map starts at version {version + 1} (its first version removes the {len(walls)} walls "
            "recorded before, and the pose starts again from odometry)"
        )
        log.error("%s", problem)
        return Resumed(offset, walls, 0, problem)

    def _restore(self, slot: PipelineSlot, recent: RecentScans, saved: SavedState, version: int) -> int:
        journal = self.db.journal(saved.version)
        steps = [v for v, _ in journal]
        if saved.version > version or steps != list(range(saved.version + 1, version + 1)):
            raise StateError(
                f"the scan journal holds {len(steps)} steps after the state: expected the steps "
                f"{saved.version + 1} to {version}"
            )
        slot.restore(MapperState.from_bytes(saved.state))
        for _, blob in journal:
            scan = scan_from_bytes(blob)
            slot.pipeline.step(scan)
            recent.add(scan)
        return len(journal)

    def after_step(
        self, slot: PipelineSlot, version: int, scan: Scan, id_offset: int
    ) -> tuple[bytes, SavedState | None]:
        """What step ``version`` records beside its map version: the scan's journal bytes and a saved
        state when one is ready. The state is taken in the step when due (a copy); its bytes are made on a
        background thread (``background``) and go with the first step recorded after they are ready, with
        the journal of the steps between kept. The first state after a start is made in the step: until
        it is recorded there is nothing to resume from."""
        journal = scan_to_bytes(scan)
        ready = self._take_ready()
        self._since += 1
        now = self._clock()
        config = slot.config
        due = (
            self._saved_at is None
            or self._since >= self.every_steps
            or now - self._saved_at >= self.every_s
            or config is not self._config
        )
        if not due or self._pending is not None:
            return journal, ready
        first = self._saved_at is None
        self._since, self._saved_at, self._config = 0, now, config
        try:
            state = slot.pipeline.state()
        except LinemapError as exc:  # mapping goes on; the journal keeps the restart exact meanwhile
            log.error("the mapping state of version %d could not be saved: %s", version, exc)
            return journal, ready
        if first or self._executor is None:
            return journal, _saved(version, state, id_offset)
        self._pending = self._executor.submit(_saved, version, state, id_offset)
        return journal, ready

    def _take_ready(self) -> SavedState | None:
        pending = self._pending
        if pending is None or not pending.done():
            return None
        self._pending = None
        try:
            return pending.result()
        except LinemapError as exc:
            log.error("the mapping state could not be saved: %s", exc)
            return None

    def close(self) -> None:
        """Stop the background thread (a state not yet recorded is dropped: the journal covers it)."""
        if self._executor is not None:
            self._executor.shutdown(wait=True, cancel_futures=True)
            self._executor = None


def _saved(version: int, state: MapperState, id_offset: int) -> SavedState:
    return SavedState(version, state.kind, state.format, id_offset, state.to_bytes())
