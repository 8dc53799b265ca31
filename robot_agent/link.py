"""The robot's side of the REST API (docs/design.md §9): long-poll messages, acknowledge them, upload maps,
download kernels.

Every call raises :class:`LinkError` on a transport failure or an unexpected status, and
:class:`UnexpectedAnswerError` (a :class:`LinkError`) on an answer that is not the API's: a redirect, a
wrong content type (a Wi-Fi login portal's HTML page answering 200), a body that is not JSON, JSON of the
wrong shape (each answer is validated against a pydantic model). ``retry_after_s`` carries the server's
``Retry-After`` once validated: a non-negative finite number of seconds or an HTTP-date, capped at
``max_retry_after_s`` (garbage is ignored, with a log line). :class:`Backoff` spaces the retries
(exponential, full jitter). See docs/reliability/agent.md.

A link may name several server processes of one fleet (one database behind them all): calls go to one of
them until it cannot answer (no response, 502, 503, 504), and from then to the next one in the list
(round robin); the caller's retry then meets the next process. Nothing else changes: uploads carry their
idempotency key and map versions, which the shared database checks, so a retried upload on another process
is neither lost nor applied twice (docs/fleet.md).
"""

from __future__ import annotations

import logging
import math
import random
import time
import uuid
from collections.abc import Sequence
from dataclasses import dataclass
from email.utils import parsedate_to_datetime
from typing import Any, TypeVar
from urllib.parse import urlsplit

import httpx
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from robot_agent.errors import LinkError, SupersededError, UnexpectedAnswerError
from shared.protocol import (
    AGENT_INSTANCE_HEADER,
    ARTIFACT_SHA256_HEADER,
    ARTIFACT_SIGNATURE_HEADER,
    ARTIFACT_STAGE_HEADER,
    MessageAck,
)

__all__ = [
    "IDLE_CONNECTION_S",
    "Backoff",
    "KernelDownload",
    "PollAnswer",
    "ServerLink",
    "UploadConflict",
    "is_transient",
    "parse_retry_after",
    "server_urls",
]

log = logging.getLogger(__name__)

#: Longest ``Retry-After`` the agent honours by default, s (a longer one is capped to this).
DEFAULT_MAX_RETRY_AFTER_S = 60.0

#: How long the agent keeps an idle connection to the server for reuse, s: shorter than the server's own
#: idle timeout (``server.cli.KEEP_ALIVE_S``), so the agent, not the server, closes an idle connection and
#: a request never goes out on a connection the server is closing at that moment.
IDLE_CONNECTION_S = 4.0

_M = TypeVar("_M", bound=BaseModel)


@dataclass
class Backoff:
    """Delays for retry ``n``: uniform in ``[0, min(cap_s, base_s * 2**n)]`` (AWS "full jitter"), and never
    less than the server's ``Retry-After`` (which is ignored unless finite and non-negative)."""

    base_s: float = 0.5
    cap_s: float = 30.0
    attempt: int = 0
    rng: random.Random | None = None

    def next_delay(self, retry_after_s: float | None = None) -> float:
        rng = self.rng or random
        delay = rng.uniform(0.0, min(self.cap_s, self.base_s * 2.0**self.attempt))
        self.attempt = min(self.attempt + 1, 30)
        if retry_after_s is None or not math.isfinite(retry_after_s) or retry_after_s < 0:
            return delay
        return max(delay, retry_after_s)

    def reset(self) -> None:
        self.attempt = 0


@dataclass(frozen=True, slots=True)
class UploadConflict:
    """The server refused an upload (409): its map is at ``current_version`` of ``current_session``;
    ``code`` says why: ``conflict`` (a version conflict in the same map session),
    ``map_session_mismatch`` (a delta of another session than the server's current one) or
    ``map_session_ended`` (the upload's session was replaced by another on the server)."""

    current_version: int
    code: str = "conflict"
    current_session: str | None = None
    #: the scan time stamp of the server's ``current_version`` (None: not said)
    current_stamp_s: float | None = None


@dataclass(frozen=True, slots=True)
class PollAnswer:
    """A long-poll's answer: the messages (each ``{"seq": int, "xml": str}``) and the map the server holds
    for this robot when it answered (``map_version`` 0: none; None: a server that does not say)."""

    messages: list[dict[str, Any]]
    map_version: int | None = None
    map_session: str | None = None


@dataclass(frozen=True, slots=True)
class KernelDownload:
    source: bytes
    sha256: str
    signature: str | None
    stage: str


class _Answer(BaseModel):
    model_config = ConfigDict(extra="ignore")


class _Message(_Answer):
    seq: int = Field(ge=1)
    xml: str


class _Messages(_Answer):
    messages: list[_Message]
    map_version: int | None = Field(None, ge=0)
    map_session: str | None = None


class _Uploaded(_Answer):
    version: int = Field(ge=0)
    map_session: str | None = None


class _Conflict(_Answer):
    error: str = "conflict"
    current_version: int = Field(0, ge=0)
    current_session: str | None = None
    current_stamp_s: float | None = None


#: Answers after which the next call goes to the next server of the list: the process is gone, restarting or
#: overloaded, and a proxy in front of it said so.
_FAILOVER_STATUSES = (502, 503, 504)


def server_urls(text: str | Sequence[str]) -> tuple[str, ...]:
    """The server URLs of ``text`` (comma-separated, or a sequence), each ``http(s)://host[:port][/path]``,
    without a trailing slash and without repeats or empty items, in order. Raises :class:`LinkError` naming
    the first one that is not such a URL, or when none is given. O(n) in the number of URLs."""
    items = text.split(",") if isinstance(text, str) else list(text)
    out: list[str] = []
    for raw in items:
        url = str(raw).strip().rstrip("/")
        if not url:  # "a,,b" or a trailing comma
            continue
        parts = urlsplit(url)
        if parts.scheme not in ("http", "https") or not parts.hostname or parts.query or parts.fragment:
            raise LinkError(f"server URL {str(raw).strip()!r}: expected http(s)://host[:port][/path]")
        try:
            parts.port  # noqa: B018 - raises ValueError on a port out of range or not a number
        except ValueError:
            raise LinkError(f"server URL {url!r}: the port is not a number in 1..65535") from None
        if url not in out:
            out.append(url)
    if not out:
        raise LinkError("no server URL given: expected one, or several separated by commas")
    return tuple(out)


def is_transient(exc: LinkError) -> bool:
    """A link failure the next attempt may not meet: no answer at all, 408, 429 or a 5xx."""
    return exc.status is None or exc.status in (408, 429) or exc.status >= 500


def parse_retry_after(value: str | None, cap_s: float, now_s: float | None = None) -> float | None:
    """``Retry-After`` as seconds to wait, in ``[0, cap_s]``; None when absent or unusable.

    Takes delta-seconds (a non-negative finite number; ``inf``, ``nan``, negatives are refused) or an
    HTTP-date (RFC 9110 §10.2.3; a past date means 0). ``now_s`` (Unix s) defaults to the wall clock."""
    if value is None:
        return None
    text = value.strip()
    try:
        seconds = float(text)
    except ValueError:
        try:
            when = parsedate_to_datetime(text)
        except (TypeError, ValueError, IndexError, OverflowError):
            log.warning("ignoring a Retry-After the agent cannot read: %r", text[:100])
            return None
        if when.tzinfo is None:  # RFC 9110 dates are GMT
            return None
        now = time.time() if now_s is None else now_s
        seconds = max(0.0, when.timestamp() - now)
    if not math.isfinite(seconds) or seconds < 0:
        log.warning("ignoring Retry-After %r: expected non-negative finite seconds", text[:100])
        return None
    if seconds > cap_s:
        log.warning("Retry-After %r capped to %.0f s", text[:100], cap_s)
        return cap_s
    return seconds


class ServerLink:
    """Calls to a server as one robot (``Authorization: Bearer`` robot token), each with this agent
    process's ``instance_id`` (a new UUID unless given) in the ``X-Linemap-Agent-Instance`` header. Any
    call the server refuses as from a superseded agent (409 ``agent_superseded``) raises
    :class:`SupersededError`, which is not retried.

    ``base_url``: one server URL, several separated by commas, or a sequence of them (the processes of one
    fleet on one database); a call that gets no answer, 502, 503 or 504 moves the link to the next one
    (:attr:`base_url` is the one in use)."""

    def __init__(
        self,
        base_url: str | Sequence[str],
        robot_id: int,
        token: str,
        *,
        timeout_s: float = 10.0,
        max_retry_after_s: float = DEFAULT_MAX_RETRY_AFTER_S,
        transport: httpx.BaseTransport | None = None,
        instance_id: str | None = None,
    ) -> None:
        self.robot_id = robot_id
        self.instance_id = instance_id or str(uuid.uuid4())
        self.max_retry_after_s = max_retry_after_s
        self.base_urls = server_urls(base_url)
        self._current = 0
        self._client = httpx.Client(
            headers={
                "Authorization": f"Bearer {token}",
                "User-Agent": "linemap-agent",
                AGENT_INSTANCE_HEADER: self.instance_id,
            },
            timeout=httpx.Timeout(timeout_s),
            limits=httpx.Limits(keepalive_expiry=IDLE_CONNECTION_S),
            transport=transport,
        )

    @property
    def base_url(self) -> str:
        """The server the next call goes to."""
        return self.base_urls[self._current]

    def close(self) -> None:
        self._client.close()

    def _fail_over(self, where: str, why: str) -> None:
        """After a call to the current server failed with ``why``: the next calls go to the next server of
        the list (nothing changes with one)."""
        if len(self.base_urls) == 1:
            return
        gone = self.base_url
        self._current = (self._current + 1) % len(self.base_urls)
        log.warning("%s at %s: %s; the next calls go to %s", where, gone, why, self.base_url)

    def _call(
        self,
        method: str,
        path: str,
        *,
        timeout_s: float | None = None,
        expect: str = "application/json",
        answers: tuple[int, ...] = (409,),
        **kwargs: Any,
    ) -> httpx.Response:
        """One request; a 4xx in ``answers`` is returned (with JSON), not raised."""
        where = f"{method} {path}"
        try:
            if timeout_s is not None:
                kwargs["timeout"] = httpx.Timeout(timeout_s)
            resp = self._client.request(method, self.base_url + "/api/v1" + path, **kwargs)
        except httpx.HTTPError as exc:
            why = f"{type(exc).__name__}: {exc or 'no response'}"
            self._fail_over(where, why)
            raise LinkError(f"{where}: {why}") from None
        if resp.status_code in _FAILOVER_STATUSES:
            self._fail_over(where, f"HTTP {resp.status_code}")
        retry = parse_retry_after(resp.headers.get("retry-after"), self.max_retry_after_s)
        ours = _content_type(resp) == "application/json"
        if resp.status_code == 409 and ours and _error_code(resp) == "agent_superseded":
            raise SupersededError(f"{where}: the server refused this agent: {_detail(resp)}")
        if resp.status_code >= 400 and resp.status_code not in answers:
            if not ours and resp.status_code not in (408, 429) and resp.status_code < 500:
                # A 4xx that is not the API's JSON: something between the robot and the server answered.
                raise UnexpectedAnswerError(where, resp, "a JSON error", retry_after_s=retry)
            raise LinkError(
                f"{where}: HTTP {resp.status_code}: {_detail(resp)}",
                status=resp.status_code,
                retry_after_s=retry,
            )
        if not 200 <= resp.status_code < 300 and resp.status_code not in answers:
            raise UnexpectedAnswerError(where, resp, f"2xx with {expect}", retry_after_s=retry)
        if resp.status_code == 204 and not expect:  # No Content: nothing to check but that it is empty
            if resp.content:
                raise UnexpectedAnswerError(where, resp, "204 with no body", retry_after_s=retry)
            return resp
        if _content_type(resp) != (expect if resp.status_code < 300 else "application/json"):
            raise UnexpectedAnswerError(where, resp, expect, retry_after_s=retry)
        return resp

    def _json(self, resp: httpx.Response, model: type[_M]) -> _M:
        try:
            return model.model_validate_json(resp.content)
        except ValidationError as exc:
            first = exc.errors(include_url=False)[0]
            at = ".".join(str(p) for p in first["loc"]) or "body"
            raise UnexpectedAnswerError(
                f"{resp.request.method} {resp.request.url.path}",
                resp,
                f"JSON like {model.__name__.lstrip('_')} ({at}: {first['msg']})",
            ) from None

    def read(self, path: str, model: type[_M], **params: Any) -> _M:
        """GET ``path`` (under ``/api/v1``) and the JSON answer validated against ``model``."""
        return self._json(self._call("GET", path, params=params or None, answers=()), model)

    def poll(self, after: int, wait_s: float) -> list[dict[str, Any]]:
        """Messages with seq above ``after``, waiting up to ``wait_s`` for one (long-poll); each
        ``{"seq": int, "xml": str}``."""
        return self.poll_answer(after, wait_s).messages

    def poll_answer(self, after: int, wait_s: float) -> PollAnswer:
        """:meth:`poll`, with the map version and session the server holds for this robot."""
        resp = self._call(
            "GET",
            f"/robots/{self.robot_id}/messages",
            params={"after": after, "wait": wait_s},
            timeout_s=wait_s + 10.0,
        )
        got = self._json(resp, _Messages)
        return PollAnswer([m.model_dump() for m in got.messages], got.map_version, got.map_session)

    def ack(self, seq: int, outcome: str, reason: str | None) -> None:
        """Report a message's outcome; a conflicting earlier acknowledgement (409) is logged, not retried,
        and so is a message the server does not hold (404: its database was restored from a backup older
        than the message)."""
        body = MessageAck.model_validate({"outcome": outcome, "reason": reason}).model_dump(mode="json")
        resp = self._call(
            "POST", f"/robots/{self.robot_id}/messages/{seq}/ack", json=body, answers=(404, 409)
        )
        if resp.status_code == 409:
            log.warning("message %d was acknowledged differently before: %s", seq, _detail(resp))
        elif resp.status_code == 404:
            log.warning(
                "the server does not hold message %d (restored from a backup?): %s", seq, _detail(resp)
            )

    def upload(self, payload: dict[str, Any], key: str) -> dict[str, Any] | UploadConflict:
        resp = self._call(
            "POST", f"/robots/{self.robot_id}/maps", json=payload, headers={"Idempotency-Key": key}
        )
        if resp.status_code == 409:
            got = self._json(resp, _Conflict)
            return UploadConflict(got.current_version, got.error, got.current_session, got.current_stamp_s)
        self._json(resp, _Uploaded)  # validated: version, and map_session when the server has sessions
        out: dict[str, Any] = resp.json()
        return out

    def report_status(self, status: dict[str, Any]) -> None:
        """Send the robot's status (a :class:`shared.protocol.RobotStatus` as JSON) without a map."""
        self._call("PUT", f"/robots/{self.robot_id}/status", json=status, answers=(), expect="")

    def fetch_kernel(self, name: str, version: str) -> KernelDownload:
        resp = self._call("GET", f"/kernels/{name}/{version}/artifact", expect="text/x-python")
        return KernelDownload(
            resp.content,
            resp.headers.get(ARTIFACT_SHA256_HEADER, ""),
            resp.headers.get(ARTIFACT_SIGNATURE_HEADER),
            resp.headers.get(ARTIFACT_STAGE_HEADER, ""),
        )


def _content_type(resp: httpx.Response) -> str:
    return str(resp.headers.get("content-type", "")).split(";")[0].strip().lower()


def _error_code(resp: httpx.Response) -> str | None:
    """The API's machine-readable ``error`` code of a JSON error answer, if any."""
    try:
        body = resp.json()
    except ValueError:
        return None
    code = body.get("error") if isinstance(body, dict) else None
    return code if isinstance(code, str) else None


def _detail(resp: httpx.Response) -> str:
    try:
        body = resp.json()
    except ValueError:
        return resp.text[:500]
    detail = body.get("detail", resp.text) if isinstance(body, dict) else resp.text
    return str(detail)[:500]
