"""Server settings (environment ``LINEMAP_*`` or arguments of ``linemap server``), validated on start."""

from __future__ import annotations

from pydantic import Field, model_validator
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
    secure_cookies: bool = Field(False, description="Mark the session cookie Secure (behind HTTPS).")
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
