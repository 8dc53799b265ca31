"""Server settings (environment ``LINEMAP_*`` or arguments of ``linemap server``), validated on start."""

from __future__ import annotations

from pydantic import Field
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
    world_extent_m: float = Field(
        10_000.0,
        gt=0,
        le=1e7,
        description="Half-width of the world, metres: every coordinate of a map upload must lie within "
        "-world_extent_m..world_extent_m (422 otherwise; exports skip stored items beyond it). The default "
        "10 km is ten times the largest single building, and keeps float64 resolution near 1e-12 m.",
    )
