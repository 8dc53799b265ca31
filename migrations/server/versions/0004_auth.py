"""auth across processes: who created each operator token and when it expires, robot token revocation and
issuer, and the shared failed-authentication counts (auth_failures)

Revision ID: 0004
Revises: 0003
Create Date: 2026-12-02 10:10:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0004"
down_revision: str | None = "0003"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("operator_tokens", schema=None) as batch_op:
        batch_op.add_column(sa.Column("created_by_id", sa.Integer(), nullable=True))
        batch_op.add_column(sa.Column("expires_at", sa.DateTime(timezone=True), nullable=True))
        batch_op.create_index(batch_op.f("ix_operator_tokens_created_by_id"), ["created_by_id"], unique=False)
        batch_op.create_foreign_key(
            batch_op.f("fk_operator_tokens_created_by_id_operator_tokens"),
            "operator_tokens",
            ["created_by_id"],
            ["id"],
            ondelete="SET NULL",
        )
    with op.batch_alter_table("robots", schema=None) as batch_op:
        batch_op.add_column(sa.Column("token_issued_by_id", sa.Integer(), nullable=True))
        batch_op.add_column(sa.Column("token_revoked_at", sa.DateTime(timezone=True), nullable=True))
        batch_op.create_index(
            batch_op.f("ix_robots_token_issued_by_id"), ["token_issued_by_id"], unique=False
        )
        batch_op.create_foreign_key(
            batch_op.f("fk_robots_token_issued_by_id_operator_tokens"),
            "operator_tokens",
            ["token_issued_by_id"],
            ["id"],
            ondelete="SET NULL",
        )
    op.create_table(
        "auth_failures",
        sa.Column("source", sa.String(length=64), nullable=False),
        sa.Column("window_start_s", sa.Float(), nullable=False),
        sa.Column("failures", sa.Integer(), nullable=False),
        sa.Column("blocked_until_s", sa.Float(), nullable=True),
        sa.PrimaryKeyConstraint("source", name=op.f("pk_auth_failures")),
    )


def downgrade() -> None:
    op.drop_table("auth_failures")
    with op.batch_alter_table("robots", schema=None) as batch_op:
        batch_op.drop_constraint(
            batch_op.f("fk_robots_token_issued_by_id_operator_tokens"), type_="foreignkey"
        )
        batch_op.drop_index(batch_op.f("ix_robots_token_issued_by_id"))
        batch_op.drop_column("token_revoked_at")
        batch_op.drop_column("token_issued_by_id")
    with op.batch_alter_table("operator_tokens", schema=None) as batch_op:
        batch_op.drop_constraint(
            batch_op.f("fk_operator_tokens_created_by_id_operator_tokens"), type_="foreignkey"
        )
        batch_op.drop_index(batch_op.f("ix_operator_tokens_created_by_id"))
        batch_op.drop_column("expires_at")
        batch_op.drop_column("created_by_id")
