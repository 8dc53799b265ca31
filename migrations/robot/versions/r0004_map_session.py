"""robot db: the map session id (meta ``map_session``), shared with the server

A Robot DB holds one map; the session id names it on the server (docs/reliability/identity.md). A new
Robot DB gets a new id here; an existing one gets one too (its map continues under it).
The agent starts another session (a new id) when the server proves to be ahead of it in this one.

Revision ID: r0004
Revises: r0003
Create Date: 2026-12-05 16:00:00.000000
"""

from __future__ import annotations

import json
import uuid
from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "r0004"
down_revision: str | None = "r0003"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

_KEYS = ("map_session", "map_session_reason")


def upgrade() -> None:
    conn = op.get_bind()
    had_map = conn.execute(sa.text("SELECT count(*) FROM map_versions")).scalar_one() > 0
    reason = "map recorded before map sessions" if had_map else "new Robot DB"
    for key, value in zip(_KEYS, (str(uuid.uuid4()), reason), strict=True):
        conn.execute(
            sa.text("INSERT OR IGNORE INTO meta (key, value) VALUES (:k, :v)"),
            {"k": key, "v": json.dumps({"v": value})},
        )


def downgrade() -> None:
    conn = op.get_bind()
    for key in _KEYS:
        conn.execute(sa.text("DELETE FROM meta WHERE key = :k"), {"k": key})
