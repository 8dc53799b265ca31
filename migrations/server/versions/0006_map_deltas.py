"""map_deltas: the last uploads of each robot's map, so that every server process can send a live-map
viewer the deltas it missed (another process's uploads, a reconnecting browser's Last-Event-ID)

Revision ID: 0006
Revises: 0005
Create Date: 2026-12-05 16:20:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0006"
down_revision: str | None = "0005"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "map_deltas",
        sa.Column("robot_id", sa.Integer(), nullable=False),
        sa.Column("version", sa.BigInteger(), nullable=False),
        sa.Column("base_version", sa.BigInteger(), nullable=True),
        sa.Column("body", sa.Text(), nullable=True),
        sa.ForeignKeyConstraint(
            ["robot_id"], ["robots.id"], name=op.f("fk_map_deltas_robot_id_robots"), ondelete="CASCADE"
        ),
        sa.PrimaryKeyConstraint("robot_id", "version", name=op.f("pk_map_deltas")),
    )


def downgrade() -> None:
    op.drop_table("map_deltas")
