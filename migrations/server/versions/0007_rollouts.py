"""rollouts: a kernel version rolled out to many robots in canaries and waves (rollouts, rollout_robots)

Revision ID: 0007
Revises: 0006
Create Date: 2026-12-05 16:30:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0007"
down_revision: str | None = "0006"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "rollouts",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("stage", sa.String(length=32), nullable=False),
        sa.Column("name", sa.String(length=64), nullable=False),
        sa.Column("version", sa.String(length=32), nullable=False),
        sa.Column("sha256", sa.String(length=64), nullable=False),
        sa.Column("state", sa.String(length=20), nullable=False),
        sa.Column("active", sa.Boolean(), nullable=False),
        sa.Column("canaries", sa.Integer(), nullable=False),
        sa.Column("wave_size", sa.Integer(), nullable=False),
        sa.Column("max_failure_share", sa.Float(), nullable=False),
        sa.Column("commit_window_s", sa.Float(), nullable=False),
        sa.Column("ack_timeout_s", sa.Float(), nullable=False),
        sa.Column("max_step_ratio", sa.Float(), nullable=True),
        sa.Column("fail_on_rollback_error", sa.Boolean(), nullable=False),
        sa.Column("wave", sa.Integer(), nullable=False),
        sa.Column("stop_reason", sa.Text(), nullable=True),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("created_by", sa.String(length=100), nullable=False),
        sa.Column("finished_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("lease_owner", sa.String(length=64), nullable=True),
        sa.Column("lease_until", sa.DateTime(timezone=True), nullable=True),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_rollouts")),
    )
    op.create_index(op.f("ix_rollouts_active"), "rollouts", ["active"], unique=False)
    op.create_table(
        "rollout_robots",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("rollout_id", sa.Integer(), nullable=False),
        sa.Column("robot_id", sa.Integer(), nullable=False),
        sa.Column("position", sa.Integer(), nullable=False),
        sa.Column("wave", sa.Integer(), nullable=False),
        sa.Column("state", sa.String(length=20), nullable=False),
        sa.Column("reason", sa.Text(), nullable=True),
        sa.Column("seq", sa.Integer(), nullable=True),
        sa.Column("rollback_seq", sa.Integer(), nullable=True),
        sa.Column("previous", sa.String(length=100), nullable=True),
        sa.Column("baseline_step_ms", sa.Float(), nullable=True),
        sa.Column("baseline_error", sa.Text(), nullable=True),
        sa.Column("sent_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("applied_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("finished_at", sa.DateTime(timezone=True), nullable=True),
        sa.Column("watch", sa.Boolean(), nullable=False),
        sa.ForeignKeyConstraint(
            ["robot_id"], ["robots.id"], name=op.f("fk_rollout_robots_robot_id_robots"), ondelete="CASCADE"
        ),
        sa.ForeignKeyConstraint(
            ["rollout_id"],
            ["rollouts.id"],
            name=op.f("fk_rollout_robots_rollout_id_rollouts"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_rollout_robots")),
        sa.UniqueConstraint("rollout_id", "robot_id", name=op.f("uq_rollout_robots_rollout_id")),
    )
    op.create_index(op.f("ix_rollout_robots_robot_id"), "rollout_robots", ["robot_id"], unique=False)
    op.create_index(op.f("ix_rollout_robots_rollout_id"), "rollout_robots", ["rollout_id"], unique=False)


def downgrade() -> None:
    op.drop_index(op.f("ix_rollout_robots_rollout_id"), table_name="rollout_robots")
    op.drop_index(op.f("ix_rollout_robots_robot_id"), table_name="rollout_robots")
    op.drop_table("rollout_robots")
    op.drop_index(op.f("ix_rollouts_active"), table_name="rollouts")
    op.drop_table("rollouts")
