"""Server settings (environment ``LINEMAP_*`` or arguments of ``linemap server``), validated on start."""

from __future__ import annotations

import ipaddress
from typing import Literal

from pydantic import Field, field_validator, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

__all__ = ["DEFAULT_DATABASE_URL", "Settings"]

DEFAULT_DATABASE_URL = "sqlite:///linemap-server.db"


class Settings(BaseSettings):
    """What the server needs to run; every field can be set as ``LINEMAP_<FIELD>`` in the environment."""

    model_config = SettingsConfigDict(env_prefix="LINEMAP_", frozen=True, extra="forbid")

    database_url: str = Field(DEFAULT_DATABASE_URL, description="SQLAlchemy URL of the server database.")
    max_body_bytes: int = Field(4 * 1024 * 1024, ge=1024, description="Largest request body (413 beyond).")
    sqlite_max_mb: float | None = Field(
        None,
        gt=0,
        description="A size limit on a SQLite database (MB): beyond it writes are refused as on a full disk "
        "(507, /healthz fails until a write succeeds again). None: the disk's size.",
    )
    max_kernel_bytes: int = Field(512 * 1024, ge=1024, description="Largest kernel module file.")
    long_poll_max_s: float = Field(60.0, gt=0, le=600, description="Longest long-poll wait a robot may ask.")
    poll_recheck_s: float = Field(
        1.0,
        gt=0,
        le=60,
        description="The safety net's period (s): a waiting map stream re-reads the database, one read "
        "checks every waiting long-poll of the process (server.pollsweep), and waiters notice a client "
        "that has gone. A safety net, since writes wake waiters at once (in this process, and on "
        "PostgreSQL in every other one through LISTEN/NOTIFY) and the notice listener resynchronises "
        "every waiter after it reconnects.",
    )
    poll_open_slots: int = Field(
        2,
        ge=1,
        le=1000,
        description="Long-polls opening at a time (server.admission); a poll that is waiting holds none.",
    )
    poll_open_floor_hz: float = Field(
        50.0,
        gt=0,
        le=100_000,
        description="Long-polls open when no other request is in progress (uploads first: server.admission), "
        "and at least this many a second when the others never pause.",
    )
    pg_writers: int = Field(
        1,
        ge=1,
        le=16,
        description="PostgreSQL: writer threads applying map uploads in group commits, each robot's always "
        "on the same one (server.writer). More take more uploads/s but slow everything else that needs "
        "the process's interpreter lock (control messages, long-polls). SQLite: always one.",
    )
    online_window_s: float = Field(10.0, gt=0, description="A robot seen within this window is online.")
    rollout_tick_s: float = Field(
        1.0, gt=0, le=60, description="The rollout driver re-reads every active rollout this often (s)."
    )
    rollout_lease_s: float = Field(
        30.0,
        gt=0,
        description="A server process drives a rollout under a lease this long (s), renewed every tick; "
        "another process takes the rollout over only after the lease ran out (docs/rollouts.md).",
    )
    session_ttl_s: float = Field(12 * 3600.0, gt=0, description="Lifetime of a browser session cookie.")
    secure_cookies: bool = Field(
        False,
        description="Always mark the session cookie Secure (it is whenever the request came over HTTPS; set "
        "this behind a TLS-terminating proxy that forwards plain HTTP).",
    )
    api_docs: bool = Field(
        False,
        description="Serve the interactive API docs at /docs (Swagger UI from a CDN, pinned by version and "
        "integrity hash, under a strict Content-Security-Policy); /openapi.json is always served.",
    )
    csrf_trusted_origins: tuple[str, ...] = Field(
        (),
        description="Origins (scheme://host[:port]) besides the server's own from which the dashboard may "
        "make state-changing requests with its session cookie, e.g. a reverse proxy's public origin "
        "(JSON list in the environment). See docs/reliability/csrf.md.",
    )
    auth_fail_limit: int = Field(
        50,
        ge=0,
        description="Failed authentications (a wrong, revoked or expired token or session, a failed login) "
        "one source (client address; IPv6: its /64) may make within auth_fail_window_s, counted by all "
        "server processes sharing the database; beyond it that source's failed attempts are answered 429 "
        "(after auth_fail_delay_s) for auth_block_s. A valid credential is never refused. 0: no limit.",
    )
    auth_fail_window_s: float = Field(
        60.0, gt=0, le=86_400, description="Window in which failed authentications are counted (s)."
    )
    auth_block_s: float = Field(
        60.0,
        gt=0,
        le=86_400,
        description="How long a source over the limit has its failed attempts refused (its Retry-After, s).",
    )
    max_walls_per_map: int = Field(
        20_000,
        ge=1,
        le=200_000,
        description="Most walls (segments) one robot's map may hold; an upload that would take the map "
        "beyond it is refused with 422 naming the cap. A large floor (10,000 m2 of offices) maps to a few "
        "thousand walls, so the default leaves several times that.",
    )
    upload_requests_per_s: float = Field(
        20.0,
        gt=0,
        description="Sustained map uploads per second one robot may make (token bucket; 429 with Retry-After "
        "beyond it). The agent uploads every 0.5 s, back to back only while it catches up.",
    )
    upload_burst_requests: float = Field(
        60.0, ge=1, description="Map uploads one robot may make at once before upload_requests_per_s applies."
    )
    upload_bytes_per_s: float = Field(
        256 * 1024,
        gt=0,
        description="Sustained map upload bytes per second one robot may send (token bucket; 429 with "
        "Retry-After beyond it). A robot at 10 Hz sends about 20 kB/s of deltas.",
    )
    upload_burst_bytes: int = Field(
        8 * 1024 * 1024,
        ge=1024,
        description="Map upload bytes one robot may send at once (at least max_body_bytes, so the largest "
        "accepted body can always pass once the bucket is full).",
    )

    @model_validator(mode="after")
    def _burst_fits_largest_body(self) -> Settings:
        if self.upload_burst_bytes < self.max_body_bytes:
            raise ValueError(
                f"upload_burst_bytes ({self.upload_burst_bytes}) must be at least max_body_bytes "
                f"({self.max_body_bytes}): a body of the largest accepted size could never pass the quota"
            )
        return self

    world_extent_m: float = Field(
        10_000.0,
        gt=0,
        le=1e7,
        description="Half-width of the world, metres: every coordinate of a map upload must lie within "
        "-world_extent_m..world_extent_m (422 otherwise; exports skip stored items beyond it). The default "
        "10 km is ten times the largest single building, and keeps float64 resolution near 1e-12 m.",
    )

    @field_validator("csrf_trusted_origins")
    @classmethod
    def _origins(cls, value: tuple[str, ...]) -> tuple[str, ...]:
        from server.csrf import normalize_origin

        out = []
        for origin in value:
            norm = normalize_origin(origin)
            if norm is None:
                raise ValueError(
                    f"{origin[:100]!r} is not an origin: expected scheme://host[:port], e.g. "
                    "https://linemap.example.org"
                )
            out.append(norm)
        return tuple(out)

    auth_fail_delay_s: float = Field(
        1.0,
        ge=0,
        le=10,
        description="A failed attempt from a source over the limit is answered only after this delay (s), "
        "so a guesser waits for every refusal; valid credentials are never delayed.",
    )
    credential_cache_s: float = Field(
        0.5,
        ge=0,
        le=1.0,
        description="How long a process may reuse a credential lookup (s); a revocation on another server "
        "process takes effect within this time. At most 1 s; 0: look up every request.",
    )
    trusted_proxies: str = Field(
        "",
        description="Comma-separated IP addresses or CIDR networks of reverse proxies whose "
        "trusted_proxy_header names the client (e.g. '10.0.0.5,192.168.1.0/24'). Default: none, so the "
        "client is always the TCP peer and forwarded headers are ignored.",
    )
    trusted_proxy_header: Literal["x-forwarded-for", "forwarded"] = Field(
        "x-forwarded-for",
        description="Which header a trusted proxy sets: X-Forwarded-For or Forwarded (RFC 7239).",
    )

    @field_validator("trusted_proxies")
    @classmethod
    def _networks(cls, value: str) -> str:
        parts = [p.strip() for p in value.split(",") if p.strip()]
        for part in parts:
            try:
                ipaddress.ip_network(part, strict=False)
            except ValueError:
                raise ValueError(
                    f"trusted_proxies entry {part!r} is not an IP address or CIDR network "
                    "(expected e.g. '10.0.0.5' or '192.168.1.0/24')"
                ) from None
        return ",".join(parts)

    def trusted_networks(self) -> list[ipaddress.IPv4Network | ipaddress.IPv6Network]:
        """:attr:`trusted_proxies` as networks (a bare address is a /32 or /128)."""
        return [ipaddress.ip_network(p, strict=False) for p in self.trusted_proxies.split(",") if p]
