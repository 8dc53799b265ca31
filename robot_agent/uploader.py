"""The agent's uploader: sends acknowledgements of control messages and the outbox (map versions as deltas,
or a snapshot when the server's base differs) from the Robot DB, in rounds.

A link fault is reported and the round retried after a backoff (the server's ``Retry-After``, validated
and capped by :mod:`robot_agent.link`, is honoured); an unexpected exception in a round is logged and
retried the same way, and one that escapes :meth:`Uploader.run` is caught by the supervisor
(:mod:`robot_agent.supervise`), which restarts it. Each round that succeeds counts as a healthy round
(:class:`~robot_agent.health.ErrorReport`). Bodies are built from :mod:`shared.protocol`'s models, the ones
the server validates them with.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

from robot_agent.errors import LinkError
from robot_agent.health import ErrorReport
from robot_agent.link import Backoff, ServerLink, UploadConflict
from robot_agent.store import RobotDB
from shared.protocol import MapDelta, MapSnapshot, RobotStatus

__all__ = ["Uploader"]

log = logging.getLogger(__name__)


class Uploader:
    """Collaborators: ``link``, ``db`` (the Robot DB), ``status`` (the status sent with each upload),
    ``wall_time`` (map version -> when its step finished, Unix s, or None), ``wake`` (set when there is
    something new), ``mapping_over`` (set once the last step is recorded), ``errors``."""

    def __init__(
        self,
        link: ServerLink,
        db: RobotDB,
        status: Callable[[], RobotStatus],
        wall_time: Callable[[int], float | None],
        wake: threading.Event,
        mapping_over: threading.Event,
        errors: ErrorReport,
        *,
        robot_id: int,
        upload_period_s: float = 0.5,
        upload_batch: int = 50,
        retry_base_s: float = 0.5,
        stop_grace_s: float = 10.0,
    ) -> None:
        self.link, self.db = link, db
        self._status, self._wall_time = status, wall_time
        self._wake, self._mapping_over, self._errors = wake, mapping_over, errors
        self.robot_id = robot_id
        self.upload_period_s = upload_period_s
        self.upload_batch = upload_batch
        self.retry_base_s = retry_base_s
        self.stop_grace_s = stop_grace_s
        self.need_snapshot = False
        self._stop_deadline: float | None = None  # the last try after a stop
        self.rounds_ok = 0

    def run(self, stop: threading.Event) -> None:
        backoff = Backoff(self.retry_base_s)
        while True:
            over = self._mapping_over.is_set()  # before the round: a step recorded during it is seen next
            try:
                acked = self.send_acks()
                sent = self.send_maps()
                busy = acked or sent
                backoff.reset()
            except LinkError as exc:
                self._errors.report(str(exc))
                if self._give_up(stop, backoff.next_delay(exc.retry_after_s)):
                    return
                continue
            except Exception as exc:  # a round that failed unexpectedly is retried, and reported
                log.exception("upload round failed")
                self._errors.report(f"upload failed: {type(exc).__name__}: {exc}")
                if self._give_up(stop, backoff.next_delay()):
                    return
                continue
            self.rounds_ok += 1
            if sent:  # a status reached the server
                self._errors.healthy_round()
            # ``stop`` may come while a step is still being recorded: the uploader ends only after a
            # round that began once the last one was recorded found nothing to send, so a clean stop
            # leaves nothing in the outbox.
            if stop.is_set() and over and not busy:
                return
            if not busy:
                self._wake.wait(self.upload_period_s)
                self._wake.clear()

    def _give_up(self, stop: threading.Event, delay_s: float) -> bool:
        """Wait ``delay_s`` before the next try after a failed round; True when the uploader should end.
        Once stopped it goes on trying for ``stop_grace_s`` (a clean stop should leave nothing in the
        outbox: one failed round just then, e.g. a connection the network had cut, left the last steps
        behind), then ends: what is left is sent at the next start."""
        if not stop.wait(delay_s):
            return False
        now = time.monotonic()
        if self._stop_deadline is None:
            self._stop_deadline = now + self.stop_grace_s
        if now >= self._stop_deadline:
            return True
        time.sleep(min(delay_s, self._stop_deadline - now))
        return False

    def send_acks(self) -> bool:
        rows = self.db.unacked()
        for row in rows:
            self.link.ack(row.seq, row.outcome, row.reason)
            self.db.mark_acked(row.seq)
        return bool(rows)

    def send_maps(self) -> bool:
        up = self.db.pending_upload(self.upload_batch)
        if up is None:
            return False
        base = self.db.get("uploaded_version")
        if self.need_snapshot or base is None or int(base) != up.first_version - 1:
            return self._send_snapshot()
        delta = MapDelta(
            version=up.version,
            base_version=int(base),
            stamp_s=up.stamp_s,
            segments=up.segments,
            removed=up.removed,
            centroids=up.centroids,
            pose=up.pose,
            trajectory=up.trajectory,
            status=self._status(),
            wall_time_s=self._wall_time(up.version),
        )
        got = self.link.upload(delta.model_dump(mode="json"), f"r{self.robot_id}-{base}-{up.version}")
        if isinstance(got, UploadConflict):
            if got.current_version >= up.version:
                self.db.mark_uploaded(got.current_version)
            else:
                self.need_snapshot = True
            return True
        self.db.mark_uploaded(up.version)
        return True

    def _send_snapshot(self) -> bool:
        snap = self.db.snapshot()
        if snap is None:
            return False
        body = MapSnapshot.model_validate(
            {**snap, "status": self._status(), "wall_time_s": self._wall_time(int(snap["version"]))}
        )
        got = self.link.upload(body.model_dump(mode="json"), f"r{self.robot_id}-snapshot-{snap['version']}")
        if isinstance(got, UploadConflict):
            if got.current_version >= snap["version"]:
                self.db.mark_uploaded(got.current_version)
                self.need_snapshot = False
                return True
            raise LinkError(
                f"the server's map of robot {self.robot_id} is at version {got.current_version}, "
                f"ahead of this robot's {snap['version']}: was the Robot DB replaced?"
            )
        self.db.mark_uploaded(int(snap["version"]))
        self.need_snapshot = False
        return True
