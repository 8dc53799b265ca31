"""map_states counts the robot's walls and poses (map_states.n_walls, map_states.n_poses), so that the
upload's wall cap and trajectory cap read two numbers instead of counting rows at every upload

Revision ID: 0012
Revises: 0011
Create Date: 2026-12-06 18:45:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0012"
down_revision: str | None = "0011"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("map_states", schema=None) as batch_op:
        batch_op.add_column(sa.Column("n_walls", sa.BigInteger(), nullable=False, server_default="0"))
        batch_op.add_column(sa.Column("n_poses", sa.BigInteger(), nullable=False, server_default="0"))
    # the rows stored before this revision, counted once
    op.execute(
        "UPDATE map_states SET "
        "n_walls = (SELECT count(*) FROM map_segments AS w WHERE w.robot_id = map_states.robot_id), "
        "n_poses = (SELECT count(*) FROM trajectory_points AS t WHERE t.robot_id = map_states.robot_id)"
    )


def downgrade() -> None:
    with op.batch_alter_table("map_states", schema=None) as batch_op:
        batch_op.drop_column("n_poses")
        batch_op.drop_column("n_walls")
