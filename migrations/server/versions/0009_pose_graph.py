"""map states keep the pose graph's keyframes, loop closures and the pose covariance (JSON, nullable)

Revision ID: 0009
Revises: 0008
Create Date: 2026-12-05 19:20:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0009"
down_revision: str | None = "0008"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

_COLUMNS = ("keyframes", "loop_closures", "pose_covariance")


def upgrade() -> None:
    with op.batch_alter_table("map_states", schema=None) as batch_op:
        for name in _COLUMNS:
            batch_op.add_column(sa.Column(name, sa.JSON(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("map_states", schema=None) as batch_op:
        for name in reversed(_COLUMNS):
            batch_op.drop_column(name)
