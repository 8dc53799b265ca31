"""robot db: kernels_run, the highest version of each kernel ever put in force (anti-rollback, docs/design.md
§9)

Backfilled from ``config_history``: every configuration a robot has put in force names the kernel versions
it ran, so a robot upgraded in the field keeps the floor its history already implies.

Revision ID: r0002
Revises: r0001
Create Date: 2026-12-01 19:45:00.000000
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterator, Sequence
from datetime import UTC, datetime
from typing import Any

import sqlalchemy as sa
from alembic import op

revision: str = "r0002"
down_revision: str | None = "r0001"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

# PipelineConfig field -> stage, as of this revision (a migration must not import the application).
_FIELDS = {
    "segmentation": "segmentation",
    "noise_removal": "noise-removal",
    "clustering": "clustering",
    "straight_line": "straight-line",
    "scan_matching": "scan-matching",
}
_VERSION = re.compile(r"^(\d+)\.(\d+)\.(\d+)$")


def _choices(config: Any) -> Iterator[tuple[str, str, tuple[int, int, int]]]:
    if not isinstance(config, dict):
        return
    for field, stage in _FIELDS.items():
        value = config.get(field)
        for choice in value if isinstance(value, list) else [value]:
            if not isinstance(choice, dict):
                continue
            name, version = choice.get("name"), choice.get("version")
            match = _VERSION.match(version) if isinstance(version, str) else None
            if isinstance(name, str) and match is not None:
                yield stage, name, (int(match[1]), int(match[2]), int(match[3]))


def upgrade() -> None:
    table = op.create_table(
        "kernels_run",
        sa.Column("stage", sa.String(length=32), nullable=False),
        sa.Column("name", sa.String(length=64), nullable=False),
        sa.Column("version", sa.String(length=32), nullable=False),
        sa.Column("seq", sa.Integer(), nullable=True),
        sa.Column("at", sa.DateTime(timezone=True), nullable=False),
        sa.PrimaryKeyConstraint("stage", "name", name=op.f("pk_kernels_run")),
    )
    highest: dict[tuple[str, str], tuple[int, int, int]] = {}
    for (raw,) in op.get_bind().execute(sa.text("SELECT config FROM config_history")):
        try:
            config = json.loads(raw) if isinstance(raw, str | bytes) else raw
        except ValueError:
            continue
        for stage, name, version in _choices(config):
            if version > highest.get((stage, name), (-1, -1, -1)):
                highest[(stage, name)] = version
    if highest:
        now = datetime.now(UTC)
        op.bulk_insert(
            table,
            [
                {"stage": s, "name": n, "version": ".".join(map(str, v)), "seq": None, "at": now}
                for (s, n), v in sorted(highest.items())
            ],
        )


def downgrade() -> None:
    op.drop_table("kernels_run")
