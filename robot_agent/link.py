"""The robot's side of the REST API (issue 4): long-poll messages, acknowledge them, upload maps, download
kernels. Every call raises :class:`LinkError` on a transport failure or an unexpected status, carrying
``retry_after_s`` when the server sent ``Retry-After``; :class:`Backoff` spaces the retries (exponential,
full jitter).
"""

from __future__ import annotations

import logging
import random
from dataclasses import dataclass
from typing import Any

import httpx

from robot_agent.errors import LinkError

__all__ = ["Backoff", "KernelDownload", "ServerLink", "UploadConflict"]

log = logging.getLogger(__name__)


@dataclass
class Backoff:
    """Delays for retry ``n``: uniform in ``[0, min(cap_s, base_s * 2**n)]`` (AWS "full jitter"), and never
    less than the server's ``Retry-After``."""

    base_s: float = 0.5
    cap_s: float = 30.0
    attempt: int = 0
    rng: random.Random | None = None

    def next_delay(self, retry_after_s: float | None = None) -> float:
        rng = self.rng or random
        delay = rng.uniform(0.0, min(self.cap_s, self.base_s * 2.0**self.attempt))
        self.attempt = min(self.attempt + 1, 30)
        return max(delay, retry_after_s or 0.0)

    def reset(self) -> None:
        self.attempt = 0


@dataclass(frozen=True, slots=True)
class UploadConflict:
    """The server refused a delta (its map is at ``current_version``): send a snapshot instead."""

    current_version: int


@dataclass(frozen=True, slots=True)
class KernelDownload:
    source: bytes
    sha256: str
    signature: str | None
    stage: str


class ServerLink:
    """Calls to one server as one robot (``Authorization: Bearer`` robot token)."""

    def __init__(self, base_url: str, robot_id: int, token: str, *, timeout_s: float = 10.0) -> None:
        self.robot_id = robot_id
        self._base = base_url.rstrip("/") + "/api/v1"
        self._client = httpx.Client(
            base_url=self._base,
            headers={"Authorization": f"Bearer {token}", "User-Agent": "linemap-agent"},
            timeout=httpx.Timeout(timeout_s),
        )

    def close(self) -> None:
        self._client.close()

    def _call(
        self, method: str, path: str, *, timeout_s: float | None = None, **kwargs: Any
    ) -> httpx.Response:
        try:
            if timeout_s is not None:
                kwargs["timeout"] = httpx.Timeout(timeout_s)
            resp = self._client.request(method, path, **kwargs)
        except httpx.HTTPError as exc:
            raise LinkError(f"{method} {path}: {type(exc).__name__}: {exc or 'no response'}") from None
        if resp.status_code >= 400 and resp.status_code != 409:
            raise LinkError(
                f"{method} {path}: HTTP {resp.status_code}: {_detail(resp)}",
                status=resp.status_code,
                retry_after_s=_retry_after(resp),
            )
        return resp

    def poll(self, after: int, wait_s: float) -> list[dict[str, Any]]:
        """Messages with seq above ``after``, waiting up to ``wait_s`` for one (long-poll)."""
        resp = self._call(
            "GET",
            f"/robots/{self.robot_id}/messages",
            params={"after": after, "wait": wait_s},
            timeout_s=wait_s + 10.0,
        )
        messages: list[dict[str, Any]] = resp.json()["messages"]
        return messages

    def ack(self, seq: int, outcome: str, reason: str | None) -> None:
        """Report a message's outcome; a conflicting earlier acknowledgement (409) is logged, not retried."""
        body = {"outcome": outcome, "reason": reason}
        resp = self._call("POST", f"/robots/{self.robot_id}/messages/{seq}/ack", json=body)
        if resp.status_code == 409:
            log.warning("message %d was acknowledged differently before: %s", seq, _detail(resp))

    def upload(self, payload: dict[str, Any], key: str) -> dict[str, Any] | UploadConflict:
        resp = self._call(
            "POST", f"/robots/{self.robot_id}/maps", json=payload, headers={"Idempotency-Key": key}
        )
        if resp.status_code == 409:
            return UploadConflict(int(resp.json().get("current_version", 0)))
        out: dict[str, Any] = resp.json()
        return out

    def fetch_kernel(self, name: str, version: str) -> KernelDownload:
        resp = self._call("GET", f"/kernels/{name}/{version}/artifact")
        return KernelDownload(
            resp.content,
            resp.headers.get("x-linemap-sha256", ""),
            resp.headers.get("x-linemap-signature"),
            resp.headers.get("x-linemap-stage", ""),
        )


def _detail(resp: httpx.Response) -> str:
    try:
        return str(resp.json().get("detail", resp.text))[:500]
    except ValueError:
        return resp.text[:500]


def _retry_after(resp: httpx.Response) -> float | None:
    value = resp.headers.get("retry-after")
    if value is None:
        return None
    try:
        return max(0.0, float(value))
    except ValueError:
        return None
