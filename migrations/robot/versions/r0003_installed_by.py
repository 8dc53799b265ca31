"""robot db: kernels.installed_by_seq, the control message that put each downloaded kernel in force

An automatic rollback reports itself as the outcome of that message ("rolled-back"); kept in the Robot DB so
it still does after an agent restart (docs/reliability/agent.md).

Revision ID: r0003
Revises: r0002
Create Date: 2026-12-02 10:30:00.000000
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "r0003"
down_revision: str | None = "r0002"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("kernels") as batch:
        batch.add_column(sa.Column("installed_by_seq", sa.Integer(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("kernels") as batch:
        batch.drop_column("installed_by_seq")
