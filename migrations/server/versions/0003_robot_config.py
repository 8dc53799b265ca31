"""robots.config and robots.kernels (what the robot runs and holds), map_states.wall_time_s (for the
dashboard's step-to-screen latency)

Revision ID: 0003
Revises: 0002
Create Date: 2026-11-22 07:30:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0003"
down_revision: str | None = "0002"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("robots", schema=None) as batch_op:
        batch_op.add_column(sa.Column("config", sa.JSON(), nullable=True))
        batch_op.add_column(sa.Column("kernels", sa.JSON(), nullable=True))
    with op.batch_alter_table("map_states", schema=None) as batch_op:
        batch_op.add_column(sa.Column("wall_time_s", sa.Float(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("map_states", schema=None) as batch_op:
        batch_op.drop_column("wall_time_s")
    with op.batch_alter_table("robots", schema=None) as batch_op:
        batch_op.drop_column("kernels")
        batch_op.drop_column("config")
