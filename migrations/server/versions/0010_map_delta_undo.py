"""map_deltas.undo: what each logged delta replaced, so that earlier versions of a map can be rebuilt

Revision ID: 0010
Revises: 0009
Create Date: 2026-12-05 19:20:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0010"
down_revision: str | None = "0009"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("map_deltas", schema=None) as batch_op:
        batch_op.add_column(sa.Column("undo", sa.Text(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("map_deltas", schema=None) as batch_op:
        batch_op.drop_column("undo")
