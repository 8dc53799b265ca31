"""Server settings (environment ``LINEMAP_*`` or arguments of ``linemap server``), validated on start."""

from __future__ import annotations

from pydantic import Field, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

__all__ = ["DEFAULT_DATABASE_URL", "Settings"]

DEFAULT_DATABASE_URL = "sqlite:///linemap-server.db"


class Settings(BaseSettings):
    """What the server needs to run; every field can be set as ``LINEMAP_<FIELD>`` in the environment."""

    model_config = SettingsConfigDict(env_prefix="LINEMAP_", frozen=True, extra="forbid")

    database_url: str = Field(DEFAULT_DATABASE_URL, description="SQLAlchemy URL of the server database.")
    max_body_bytes: int = Field(4 * 1024 * 1024, ge=1024, description="Largest request body (413 beyond).")
    max_kernel_bytes: int = Field(512 * 1024, ge=1024, description="Largest kernel module file.")
    long_poll_max_s: float = Field(60.0, gt=0, le=600, description="Longest long-poll wait a robot may ask.")
    poll_recheck_s: float = Field(
        1.0,
        gt=0,
        le=60,
        description="A waiting long-poll or stream re-reads the database this often "
        "(covers writes by other server processes sharing a PostgreSQL database).",
    )
    online_window_s: float = Field(10.0, gt=0, description="A robot seen within this window is online.")
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
        "one client address may make within auth_fail_window_s; beyond it the address's API requests that "
        "carry a credential get 429 for auth_block_s. 0 switches the limit off.",
    )
    auth_fail_window_s: float = Field(
        60.0, gt=0, le=86_400, description="Sliding window in which failed authentications are counted."
    )
    auth_block_s: float = Field(
        60.0, gt=0, le=86_400, description="How long a client over the limit is refused (its Retry-After)."
    )

    @field_validator("csrf_trusted_origins")
    @classmethod
    def _origins(cls, value: tuple[str, ...]) -> tuple[str, ...]:
        from server.csrf import normalize_origin

        out = []
        for origin in value:
            norm = normalize_origin(origin)
            if norm is None:
                raise ValueError(f"{origin[:100]!r} is not an origin: expected scheme://host[:port], e.g. "
                                 "https://linemap.example.org")
            out.append(norm)
        return tuple(out)
