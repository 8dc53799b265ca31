"""robot db: mapping_state and scan_journal, so a restarted agent goes on with the same map at the same pose

``mapping_state`` holds the pipeline's learned state at a recorded map version (one row, replaced at each
checkpoint); ``scan_journal`` the scans mapped since, re-stepped on a restart (docs/reliability/agent.md).
A Robot DB from before this revision has no state: its agent starts a new map over the old one.

Revision ID: r0005
Revises: r0004
Create Date: 2026-12-05 16:20:00.000000
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "r0005"
down_revision: str | None = "r0004"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "mapping_state",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("version", sa.Integer(), nullable=False),
        sa.Column("kind", sa.String(length=16), nullable=False),
        sa.Column("format", sa.Integer(), nullable=False),
        sa.Column("id_offset", sa.Integer(), nullable=False),
        sa.Column("state", sa.LargeBinary(), nullable=False),
        sa.Column("saved_at", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("id", name=op.f("pk_mapping_state")),
    )
    op.create_table(
        "scan_journal",
        sa.Column("version", sa.Integer(), nullable=False),
        sa.Column("scan", sa.LargeBinary(), nullable=False),
        sa.PrimaryKeyConstraint("version", name=op.f("pk_scan_journal")),
    )


def downgrade() -> None:
    op.drop_table("scan_journal")
    op.drop_table("mapping_state")
