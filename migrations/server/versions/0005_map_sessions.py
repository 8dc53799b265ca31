"""map sessions: one map per (robot, mapping session), ended sessions' maps kept; the agent process that
speaks for each robot (robots.agent_instance, agent_instances); the session of each recorded upload

Revision ID: 0005
Revises: 0004
Create Date: 2026-12-05 16:20:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0005"
down_revision: str | None = "0004"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

_WHEN = sa.DateTime(timezone=True)
_ID64 = sa.BigInteger().with_variant(sa.Integer(), "sqlite")


def upgrade() -> None:
    with op.batch_alter_table("robots", schema=None) as batch_op:
        batch_op.add_column(sa.Column("map_session", sa.String(length=36), nullable=True))
        batch_op.add_column(sa.Column("agent_instance", sa.String(length=36), nullable=True))
        batch_op.add_column(sa.Column("agent_since", _WHEN, nullable=True))
    with op.batch_alter_table("map_uploads", schema=None) as batch_op:
        batch_op.add_column(sa.Column("map_session", sa.String(length=36), nullable=True))
    op.create_table(
        "map_sessions",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("robot_id", sa.Integer(), nullable=False),
        sa.Column("session_id", sa.String(length=36), nullable=True),
        sa.Column("started_at", _WHEN, nullable=False),
        sa.Column("first_version", sa.BigInteger(), nullable=True),
        sa.Column("reason", sa.String(length=300), nullable=True),
        sa.Column("ended_at", _WHEN, nullable=True),
        sa.Column("last_version", sa.BigInteger(), nullable=True),
        sa.Column("last_upload_at", _WHEN, nullable=True),
        sa.Column("wall_count", sa.Integer(), nullable=True),
        sa.Column("state", sa.JSON(), nullable=True),
        sa.ForeignKeyConstraint(
            ["robot_id"], ["robots.id"], name=op.f("fk_map_sessions_robot_id_robots"), ondelete="CASCADE"
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_map_sessions")),
    )
    with op.batch_alter_table("map_sessions", schema=None) as batch_op:
        batch_op.create_index("ix_map_sessions_robot_session", ["robot_id", "session_id"], unique=False)
    op.create_table(
        "map_session_segments",
        sa.Column("session_pk", sa.Integer(), nullable=False),
        sa.Column("segment_id", sa.BigInteger(), nullable=False),
        sa.Column("x0_m", sa.Float(), nullable=False),
        sa.Column("y0_m", sa.Float(), nullable=False),
        sa.Column("x1_m", sa.Float(), nullable=False),
        sa.Column("y1_m", sa.Float(), nullable=False),
        sa.Column("version", sa.BigInteger(), nullable=False),
        sa.ForeignKeyConstraint(
            ["session_pk"],
            ["map_sessions.id"],
            name=op.f("fk_map_session_segments_session_pk_map_sessions"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("session_pk", "segment_id", name=op.f("pk_map_session_segments")),
    )
    op.create_table(
        "map_session_trajectory",
        sa.Column("id", _ID64, nullable=False),
        sa.Column("session_pk", sa.Integer(), nullable=False),
        sa.Column("version", sa.BigInteger(), nullable=False),
        sa.Column("stamp_s", sa.Float(), nullable=False),
        sa.Column("x_m", sa.Float(), nullable=False),
        sa.Column("y_m", sa.Float(), nullable=False),
        sa.Column("theta_rad", sa.Float(), nullable=False),
        sa.ForeignKeyConstraint(
            ["session_pk"],
            ["map_sessions.id"],
            name=op.f("fk_map_session_trajectory_session_pk_map_sessions"),
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_map_session_trajectory")),
    )
    with op.batch_alter_table("map_session_trajectory", schema=None) as batch_op:
        batch_op.create_index("ix_map_session_trajectory_session", ["session_pk", "id"], unique=False)
    op.create_table(
        "agent_instances",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("robot_id", sa.Integer(), nullable=False),
        sa.Column("instance_id", sa.String(length=36), nullable=False),
        sa.Column("first_seen_at", _WHEN, nullable=False),
        sa.Column("superseded_at", _WHEN, nullable=True),
        sa.ForeignKeyConstraint(
            ["robot_id"], ["robots.id"], name=op.f("fk_agent_instances_robot_id_robots"), ondelete="CASCADE"
        ),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_agent_instances")),
        sa.UniqueConstraint("robot_id", "instance_id", name=op.f("uq_agent_instances_robot_id")),
    )


def downgrade() -> None:
    op.drop_table("agent_instances")
    with op.batch_alter_table("map_session_trajectory", schema=None) as batch_op:
        batch_op.drop_index("ix_map_session_trajectory_session")
    op.drop_table("map_session_trajectory")
    op.drop_table("map_session_segments")
    with op.batch_alter_table("map_sessions", schema=None) as batch_op:
        batch_op.drop_index("ix_map_sessions_robot_session")
    op.drop_table("map_sessions")
    with op.batch_alter_table("map_uploads", schema=None) as batch_op:
        batch_op.drop_column("map_session")
    with op.batch_alter_table("robots", schema=None) as batch_op:
        batch_op.drop_column("agent_since")
        batch_op.drop_column("agent_instance")
        batch_op.drop_column("map_session")
