"""The Robot DB's control tables as the agent uses them: the outcome of every control message and the
configuration it put in force (one transaction), the kernel versions' anti-rollback floors (docs/design.md §9,
only ever raised), acknowledgements, and the downloaded kernels' records and states.

Every method is one transaction or one read, O(rows touched).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from robot_agent.models import AppliedMessage, ConfigRecord, KernelRecord, RunFloor, utcnow
from robot_agent.store_db import RobotDBFile, put_meta
from shared.kernels.versions import parse_version

__all__ = ["ControlTables", "Ran"]

#: Kernel versions a configuration puts in force: ``(stage, name, version)``.
Ran = Sequence[tuple[str, str, str]]


class ControlTables(RobotDBFile):
    """The control-message and kernel methods of :class:`robot_agent.store.RobotDB`."""

    def applied_seq(self) -> int:
        """The highest message number dealt with (applied or rejected)."""
        with self._factory() as s:
            return int(s.scalar(select(func.max(AppliedMessage.seq))) or 0)

    def outcome_of(self, seq: int) -> AppliedMessage | None:
        with self._factory() as s:
            return s.get(AppliedMessage, seq)

    def record_message(
        self,
        seq: int,
        outcome: str,
        reason: str | None,
        config: dict[str, Any] | None,
        note: str = "",
        ran: Ran = (),
        installed: Ran = (),
    ) -> None:
        """A message's outcome, the configuration it put in force and the kernel versions that configuration
        runs (``ran``, raising their anti-rollback floors), and the downloaded kernels it brought in
        (``installed``: their ``installed_by_seq`` becomes ``seq``), in one transaction."""
        with self.tx() as s:
            s.add(AppliedMessage(seq=seq, outcome=outcome, reason=reason))
            if config is not None:
                s.add(ConfigRecord(seq=seq, config=config, note=note))
                put_meta(s, "config", config)
                _raise_floors(s, ran, seq)
            for stage, name, version in installed:
                row = _kernel(s, stage, name, version)
                if row is not None:
                    row.installed_by_seq = seq

    def take_installed_by(self, stage: str, name: str, version: str) -> int | None:
        """The message that installed this downloaded kernel (None if none is recorded), forgotten in the
        same transaction: its rollback is reported once."""
        with self.tx() as s:
            row = _kernel(s, stage, name, version)
            if row is None or row.installed_by_seq is None:
                return None
            seq, row.installed_by_seq = row.installed_by_seq, None
            return int(seq)

    def record_config(self, config: dict[str, Any], note: str, ran: Ran = ()) -> None:
        """A configuration put in force without a message (start-up, automatic rollback), and the kernel
        versions it runs."""
        with self.tx() as s:
            s.add(ConfigRecord(seq=None, config=config, note=note))
            put_meta(s, "config", config)
            _raise_floors(s, ran, None)

    def run_floors(self) -> dict[tuple[str, str], str]:
        """``(stage, name) -> version``: the highest version of each kernel this robot has put in force
        (docs/design.md §9 anti-rollback floor; kept across restarts). One read of a table with a row per
        kernel name.
        """
        with self._factory() as s:
            return {(r.stage, r.name): r.version for r in s.scalars(select(RunFloor))}

    def mark_rolled_back(self, seq: int, reason: str) -> None:
        """The kernel message ``seq`` brought in failed at run time: report it again as rolled back."""
        with self.tx() as s:
            row = s.get(AppliedMessage, seq)
            if row is not None:
                row.outcome, row.reason, row.acked_at = "rolled-back", reason, None

    def unacked(self) -> list[AppliedMessage]:
        with self._factory() as s:
            return list(
                s.scalars(
                    select(AppliedMessage)
                    .where(AppliedMessage.acked_at.is_(None))
                    .order_by(AppliedMessage.seq)
                )
            )

    def mark_acked(self, seq: int) -> None:
        with self.tx() as s:
            row = s.get(AppliedMessage, seq)
            if row is not None and row.acked_at is None:
                row.acked_at = utcnow()

    # ------------------------------------------------------------------ kernels
    def save_kernel(self, rec: KernelRecord) -> None:
        with self.tx() as s:
            old = s.scalars(
                select(KernelRecord).where(
                    KernelRecord.stage == rec.stage,
                    KernelRecord.name == rec.name,
                    KernelRecord.version == rec.version,
                )
            ).first()
            if old is not None:
                s.delete(old)
                s.flush()
            s.add(rec)

    def set_kernel_state(
        self, stage: str, name: str, version: str, state: str, reason: str | None = None
    ) -> None:
        with self.tx() as s:
            row = s.scalars(
                select(KernelRecord).where(
                    KernelRecord.stage == stage, KernelRecord.name == name, KernelRecord.version == version
                )
            ).first()
            if row is not None:
                row.state, row.reason = state, reason

    def kernels(self, states: Sequence[str] | None = None) -> list[KernelRecord]:
        with self._factory() as s:
            q = select(KernelRecord).order_by(KernelRecord.id)
            if states is not None:
                q = q.where(KernelRecord.state.in_(list(states)))
            return list(s.scalars(q))


def _kernel(s: Session, stage: str, name: str, version: str) -> KernelRecord | None:
    return s.scalars(
        select(KernelRecord).where(
            KernelRecord.stage == stage, KernelRecord.name == name, KernelRecord.version == version
        )
    ).first()


def _raise_floors(s: Session, ran: Ran, seq: int | None) -> None:
    """Raise each ``(stage, name)`` floor to ``version`` if that is higher (never lowers one)."""
    for stage, name, version in ran:
        row = s.get(RunFloor, (stage, name))
        if row is None:
            s.add(RunFloor(stage=stage, name=name, version=version, seq=seq))
            s.flush()
        elif parse_version(version) > parse_version(row.version):
            row.version, row.seq, row.at = version, seq, utcnow()
