"""The agent's uploader: sends acknowledgements of control messages and the outbox (map versions as deltas,
or a snapshot when the server's base differs) from the Robot DB, in rounds. A version is marked delivered
only when the server confirms it holds it in this Robot DB's map session (see :meth:`Uploader.send_maps`).

A link fault is reported and the round retried after a backoff (the server's ``Retry-After``, validated
and capped by :mod:`robot_agent.link`, is honoured); an unexpected exception in a round is logged and
retried the same way, and one that escapes :meth:`Uploader.run` is caught by the supervisor
(:mod:`robot_agent.supervise`), which restarts it. Each round that succeeds counts as a healthy round
(:class:`~robot_agent.health.ErrorReport`). Bodies are built from :mod:`shared.protocol`'s models, the ones
the server validates them with. A round with nothing to upload sends the status alone when its
``last_error`` changed since the server last heard it (:meth:`Uploader.send_status`): a robot whose
recording paused on a full disk has no map to send, and the server still learns why. A round that fails
because the Robot DB's disk is full is reported as such, without a traceback.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable
from typing import Any

from robot_agent.errors import LinkError, SupersededError
from robot_agent.health import ErrorReport
from robot_agent.link import Backoff, ServerLink, UploadConflict
from robot_agent.store import RobotDB
from shared.diskfull import disk_full_reason
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
        retry_cap_s: float = 30.0,
        stop_grace_s: float = 10.0,
    ) -> None:
        self.link, self.db = link, db
        self._status, self._wall_time = status, wall_time
        self._wake, self._mapping_over, self._errors = wake, mapping_over, errors
        self.robot_id = robot_id
        self.upload_period_s = upload_period_s
        self.upload_batch = upload_batch
        self.retry_base_s, self.retry_cap_s = retry_base_s, retry_cap_s
        self.stop_grace_s = stop_grace_s
        self.need_snapshot = False
        self._stop_deadline: float | None = None  # the last try after a stop
        self.rounds_ok = 0
        self._told_error: str | None = None  # the last_error the server heard last

    def run(self, stop: threading.Event) -> None:
        backoff = Backoff(self.retry_base_s, self.retry_cap_s)
        while True:
            over = self._mapping_over.is_set()  # before the round: a step recorded during it is seen next
            try:
                acked = self.send_acks()
                sent = self.send_maps() or self.send_status()
                busy = acked or sent
                backoff.reset()
            except SupersededError:
                raise  # another agent took over: this one stops (the supervisor's fatal path)
            except LinkError as exc:
                self._errors.report(str(exc))
                if self._give_up(stop, backoff.next_delay(exc.retry_after_s)):
                    return
                continue
            except Exception as exc:  # a round that failed unexpectedly is retried, and reported
                full = disk_full_reason(exc)
                if full is not None:  # the Robot DB could not note a delivery: the server has it, retried
                    log.error("upload round: the Robot DB's disk is full (%s); retried", full)
                    if "disk is full" not in (self._errors.message or ""):  # the mapping's pause says more
                        self._errors.report(f"the Robot DB's disk is full ({full}): uploads retried")
                    with contextlib.suppress(LinkError):  # a repeated upload's status is not applied
                        self.send_status(unsure=True)
                else:
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

    def resend_map(self, reason: str) -> None:
        """The server lost map versions it had confirmed (``reason`` says what it holds): send the whole map
        as a snapshot in the next round, even if nothing new was recorded (the poller calls this from its
        thread; the flag is read in the next round)."""
        if not self.need_snapshot:
            log.warning("%s: sending the map again as a snapshot", reason)
        self.need_snapshot = True
        self._wake.set()

    def send_status(self, *, unsure: bool = False) -> bool:
        """Send the status alone if its ``last_error`` differs from what the server heard last (a round
        with nothing else to send), or whatever it is when ``unsure`` (the server may not have applied
        what was sent: a repeated upload is answered from its first answer, its status not applied);
        True when it was sent."""
        status = self._status()
        if status.last_error == self._told_error and not unsure:
            return False
        self.link.report_status(status.model_dump(mode="json"))
        self._told_error = status.last_error
        return True

    def send_acks(self) -> bool:
        rows = self.db.unacked()
        for row in rows:
            self.link.ack(row.seq, row.outcome, row.reason)
            self.db.mark_acked(row.seq)
        return bool(rows)

    def send_maps(self) -> bool:
        """Send what the outbox holds: a delta from the version the server confirmed, or a snapshot.

        Map identity (docs/reliability/identity.md): every upload carries this Robot DB's map session, and a
        version counts as delivered only when the server answers that it holds it in this session. A 409
        never marks anything delivered: a delta of another session than the server's, or from another
        base, is followed by a snapshot; a server at or ahead of this robot in the same session at a version
        this robot recorded with the same scan stamp holds this robot's own uploads (an answer was lost:
        the robot goes on from there); one ahead with a map this robot did not make (the Robot DB was
        restored from an older copy, or another agent uploaded there), or one that ended this session,
        makes the robot start a new session, so the server keeps the old map and starts a new one."""
        up = self.db.pending_upload(self.upload_batch)
        if up is None:  # nothing new; the map again if the server lost it (see :meth:`resend_map`)
            return self._send_snapshot() if self.need_snapshot else False
        base = self.db.get("uploaded_version")
        if self.need_snapshot or base is None or int(base) != up.first_version - 1:
            return self._send_snapshot()
        session = self.db.map_session()
        delta = MapDelta(
            map_session=session,
            version=up.version,
            base_version=int(base),
            stamp_s=up.stamp_s,
            segments=up.segments,
            removed=up.removed,
            centroids=up.centroids,
            pose=up.pose,
            trajectory=up.trajectory,
            keyframes=up.keyframes,
            loop_closures=up.loop_closures,
            pose_covariance=up.pose_covariance,
            status=self._status(),
            wall_time_s=self._wall_time(up.version),
        )
        self._told_error = delta.status.last_error if delta.status else None
        got = self.link.upload(
            delta.model_dump(mode="json"), f"r{self.robot_id}-{session}-{base}-{up.version}"
        )
        if isinstance(got, UploadConflict):
            self._conflict(got, session, up.version)
            return True
        self._confirmed(got, session, up.version)
        return True

    def _send_snapshot(self) -> bool:
        snap = self.db.snapshot()
        if snap is None:
            return False
        session = self.db.map_session()
        version = int(snap["version"])
        body = MapSnapshot.model_validate(
            {
                **snap,
                "map_session": session,
                "map_session_reason": self.db.map_session_reason(),
                "status": self._status(),
                "wall_time_s": self._wall_time(version),
            }
        )
        self._told_error = body.status.last_error if body.status else None
        got = self.link.upload(body.model_dump(mode="json"), f"r{self.robot_id}-{session}-snapshot-{version}")
        if isinstance(got, UploadConflict):
            self._conflict(got, session, version)
            return True
        self._confirmed(got, session, version)
        self.need_snapshot = False
        return True

    def _confirmed(self, got: dict[str, Any], session: str, version: int) -> None:
        """Mark ``version`` delivered if the server's answer says it holds it in ``session``; else the
        answer is not the server's word on this upload (a link fault: retried)."""
        held, in_session = got.get("version"), got.get("map_session")
        if held != version or (in_session is not None and in_session != session):
            raise LinkError(
                f"the server answered an upload of version {version} of map session {session} with version "
                f"{held} of session {in_session}: not marked delivered"
            )
        self.db.mark_uploaded(version)

    def _own_lost_answer(self, got: UploadConflict) -> bool:
        """Whether the server's map (same session, at ``got.current_version``) is this robot's own: it
        recorded that version and not yet past what it has, with the very scan stamp the server names."""
        if got.code != "conflict" or got.current_stamp_s is None:
            return False
        mine = self.db.stamp_of(got.current_version)
        return mine is not None and abs(mine - got.current_stamp_s) <= 1e-6

    def _conflict(self, got: UploadConflict, session: str, version: int) -> None:
        """What a 409 to an upload of ``version`` in ``session`` means for the next upload (nothing is
        marked delivered but what the server names as held)."""
        if self._own_lost_answer(got):
            # the server holds a version this robot recorded, with the same scan stamp, in this session:
            # an answer that never arrived (the agent was killed, the connection cut); go on from there
            log.info(
                "the server holds version %d of map session %s already (an answer lost): going on from it",
                got.current_version,
                session,
            )
            self.db.mark_uploaded(got.current_version)
            self.need_snapshot = False
            return
        if got.code == "map_session_mismatch" or (got.code == "conflict" and got.current_version < version):
            log.info(
                "the server's map of robot %d is at version %d of session %s; sending a snapshot of "
                "version %d of session %s",
                self.robot_id,
                got.current_version,
                got.current_session,
                version,
                session,
            )
            self.need_snapshot = True
            return
        if got.code == "map_session_ended":
            reason = (
                f"the server ended map session {session} (its current map is session {got.current_session}): "
                "another map replaced it"
            )
        else:  # the same session, and the server holds this version or a later one already
            reason = (
                f"the server's map of session {session} is at version {got.current_version}, at or ahead "
                f"of this robot's {version}: the Robot DB was restored from an older copy, or another "
                "agent uploaded in this session"
            )
        new = self.db.new_map_session(reason)
        log.warning(
            "robot %d starts a new map session %s (the server keeps the old map): %s",
            self.robot_id,
            new,
            reason,
        )
        self.need_snapshot = True
