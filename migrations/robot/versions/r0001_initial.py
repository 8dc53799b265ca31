"""robot db: meta, kernels, config history, map versions, walls, poses, outbox, applied messages

Revision ID: r0001
Revises: (none)
Create Date: 2026-11-22 04:55:50.952242
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "r0001"
down_revision: str | None = None
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "applied_messages",
        sa.Column("seq", sa.Integer(), nullable=False),
        sa.Column("outcome", sa.String(length=16), nullable=False),
        sa.Column("reason", sa.Text(), nullable=True),
        sa.Column("applied_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("acked_at", sa.DateTime(timezone=True), nullable=True),
        sa.PrimaryKeyConstraint("seq", name=op.f("pk_applied_messages")),
    )
    op.create_table(
        "config_history",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("seq", sa.Integer(), nullable=True),
        sa.Column("config", sa.JSON(), nullable=False),
        sa.Column("note", sa.String(length=200), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_config_history")),
    )
    op.create_table(
        "kernels",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("stage", sa.String(length=32), nullable=False),
        sa.Column("name", sa.String(length=64), nullable=False),
        sa.Column("version", sa.String(length=32), nullable=False),
        sa.Column("sha256", sa.String(length=64), nullable=False),
        sa.Column("source", sa.LargeBinary(), nullable=False),
        sa.Column("signature", sa.String(length=100), nullable=True),
        sa.Column("key_id", sa.String(length=16), nullable=True),
        sa.Column("state", sa.String(length=16), nullable=False),
        sa.Column("reason", sa.Text(), nullable=True),
        sa.Column("installed_at", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_kernels")),
        sa.UniqueConstraint("stage", "name", "version", name=op.f("uq_kernels_stage")),
    )
    op.create_table(
        "map_versions",
        sa.Column("version", sa.Integer(), nullable=False),
        sa.Column("stamp_s", sa.Float(), nullable=False),
        sa.Column("source_index", sa.Integer(), nullable=False),
        sa.Column("change", sa.JSON(), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("version", name=op.f("pk_map_versions")),
    )
    op.create_table(
        "meta",
        sa.Column("key", sa.String(length=50), nullable=False),
        sa.Column("value", sa.JSON(), nullable=False),
        sa.PrimaryKeyConstraint("key", name=op.f("pk_meta")),
    )
    op.create_table(
        "outbox",
        sa.Column("version", sa.Integer(), nullable=False),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.Column("attempts", sa.Integer(), nullable=False),
        sa.PrimaryKeyConstraint("version", name=op.f("pk_outbox")),
    )
    op.create_table(
        "poses",
        sa.Column("version", sa.Integer(), nullable=False),
        sa.Column("stamp_s", sa.Float(), nullable=False),
        sa.Column("x_m", sa.Float(), nullable=False),
        sa.Column("y_m", sa.Float(), nullable=False),
        sa.Column("theta_rad", sa.Float(), nullable=False),
        sa.PrimaryKeyConstraint("version", name=op.f("pk_poses")),
    )
    op.create_table(
        "walls",
        sa.Column("segment_id", sa.Integer(), nullable=False),
        sa.Column("x0_m", sa.Float(), nullable=False),
        sa.Column("y0_m", sa.Float(), nullable=False),
        sa.Column("x1_m", sa.Float(), nullable=False),
        sa.Column("y1_m", sa.Float(), nullable=False),
        sa.PrimaryKeyConstraint("segment_id", name=op.f("pk_walls")),
    )


def downgrade() -> None:
    op.drop_table("walls")
    op.drop_table("poses")
    op.drop_table("outbox")
    op.drop_table("meta")
    op.drop_table("map_versions")
    op.drop_table("kernels")
    op.drop_table("config_history")
    op.drop_table("applied_messages")
