"""The agent's poller: long-polls the server for control messages, prepares each (parse, download and
verify kernels: see ``Agent._prepare``) and hands it to the mapping thread through a queue.

Any link fault (no answer, an error status, an answer that is not the API's, see :mod:`robot_agent.link`)
is reported and retried after a backoff: whatever the network answers, the loop goes on. An exception it
does not expect ends :meth:`Poller.run`; the supervisor (:mod:`robot_agent.supervise`) restarts it.

Each answer also says which map version and session the server holds for this robot. The server's map
never goes back within a session, so when it holds less than the version it had confirmed before the poll
was sent, it lost versions (its database was restored from an older copy, docs/reliability/identity.md):
the poller tells the uploader (``map_lost``), which sends the map again as a snapshot even when the
robot has nothing new to send.
"""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable
from typing import Any

from robot_agent.control import Prepared
from robot_agent.errors import LinkError
from robot_agent.health import ErrorReport
from robot_agent.link import Backoff, PollAnswer, ServerLink

__all__ = ["Poller"]

log = logging.getLogger(__name__)


class Poller:
    """Collaborators: ``link`` (the server), ``applied_seq`` (the highest message dealt with, from the Robot
    DB), ``prepare`` (a raw message to a :class:`Prepared`; raises :class:`LinkError` on a download fault),
    ``inbox`` (to the mapping thread), ``errors`` (last_error); ``delivered_map`` (the Robot DB's map
    session and the newest version the server confirmed, or None) and ``map_lost`` (told why the server
    must be sent the map again) check the server's map after each poll, when both are given."""

    def __init__(
        self,
        link: ServerLink,
        applied_seq: Callable[[], int],
        prepare: Callable[[dict[str, Any]], Prepared],
        inbox: queue.Queue[Prepared],
        errors: ErrorReport,
        *,
        poll_wait_s: float = 20.0,
        retry_base_s: float = 0.5,
        retry_cap_s: float = 30.0,
        delivered_map: Callable[[], tuple[str, int | None]] | None = None,
        map_lost: Callable[[str], None] | None = None,
    ) -> None:
        self.link = link
        self._applied_seq = applied_seq
        self._prepare = prepare
        self._inbox = inbox
        self._errors = errors
        self.poll_wait_s = poll_wait_s
        self.retry_base_s, self.retry_cap_s = retry_base_s, retry_cap_s
        self._delivered_map, self._map_lost = delivered_map, map_lost
        self.handed = 0  # the highest seq handed to the mapping thread (kept across restarts of run)
        self.polls_ok = 0

    def run(self, stop: threading.Event) -> None:
        backoff = Backoff(self.retry_base_s, self.retry_cap_s)
        download_backoff = Backoff(self.retry_base_s, self.retry_cap_s)
        while not stop.is_set():
            after = max(self._applied_seq(), self.handed)
            held = self._delivered_map() if self._delivered_map is not None else None
            try:
                answer = self.link.poll_answer(after, self.poll_wait_s)
            except LinkError as exc:
                self._errors.report(str(exc))
                log.warning("poll failed, retrying: %s", exc)
                stop.wait(backoff.next_delay(exc.retry_after_s))
                continue
            backoff.reset()
            self.polls_ok += 1
            if stop.is_set():
                return
            if held is not None:
                self._check_map(held, answer)
            for raw in answer.messages:
                seq = int(raw["seq"])
                if seq <= after:
                    continue
                try:
                    prepared = self._prepare(raw)
                except LinkError as exc:  # a kernel download failed in transit: poll it again
                    self._errors.report(str(exc))
                    log.warning("message %s: kernel download failed, retrying: %s", seq, exc)
                    stop.wait(download_backoff.next_delay(exc.retry_after_s))
                    break
                download_backoff.reset()
                self._inbox.put(prepared)
                self.handed = after = seq

    def _check_map(self, held: tuple[str, int | None], answer: PollAnswer) -> None:
        """Tell ``map_lost`` when the server holds less than the version ``held`` it confirmed before the
        poll (in the same session), or another session's map, or none. O(1)."""
        session, version = held
        if answer.map_version is None or version is None or self._map_lost is None:
            return  # a server that does not say, or nothing confirmed in this session yet
        if answer.map_session == session and answer.map_version >= version:
            return
        assert self._delivered_map is not None
        if self._delivered_map()[0] != session:
            return  # the robot started a new session during the poll: its snapshot goes out anyway
        self._map_lost(
            f"the server holds version {answer.map_version} of map session {answer.map_session}, not "
            f"version {version} of session {session} that it confirmed (restored from an older copy?)"
        )
