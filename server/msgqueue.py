"""Queue one control message for a robot: the one path every sender takes (operators through
``POST /robots/{id}/messages``, the rollout driver for its updates and rollbacks).

The message is checked as the robot will check it (kernel operations name a kernel version the server
holds, with its sha256 and stage; parameters and configuration by :func:`server.msgcheck.check_like_robot`),
numbered next in the robot's sequence, written with a ``message.post`` audit entry (and a
``kernel.below_floor`` entry per ``<kernel-rollback below-floor="allow">``), and announced to the other
server processes (PostgreSQL ``NOTIFY``, delivered at commit: :meth:`server.hub.Hub.announce`). The caller
owns the transaction and, after it commits, wakes this process's long-polls with
``hub.publish(f"messages:{robot_id}", seq)``. All checks run before the first write, so a refused message
leaves the caller's session untouched. O(operations) queries.
"""

from __future__ import annotations

from typing import Any

from sqlalchemy import select, update
from sqlalchemy.orm import Session

from server.errors import InvalidRequestError, NotFoundError
from server.hub import Hub
from server.models import AuditEntry, KernelArtifact, Message, Robot
from server.msgcheck import check_like_robot
from shared.control import ControlMessage, OperationKind

__all__ = ["check_operations", "queue_message"]


def check_operations(s: Session, msg: ControlMessage) -> None:
    """Every ``<kernel-install>``/``<kernel-update>`` names a kernel version the server holds (not deleted),
    with its sha256 and of its stage; :class:`InvalidRequestError` naming the element and line otherwise."""
    for op in msg.operations:
        if op.kind not in (OperationKind.INSTALL, OperationKind.UPDATE):
            continue
        art = s.scalars(
            select(KernelArtifact).where(KernelArtifact.name == op.name, KernelArtifact.version == op.version)
        ).first()
        where = f"line {op.line} " if op.line else ""
        element = f"<{op.kind.value}>"
        if art is None or art.deleted_at is not None:
            state = "was deleted" if art is not None else "is not on the server"
            raise InvalidRequestError(
                f"{where}{element}: kernel {op.name} {op.version} {state}; upload it first",
                element=element,
                line=op.line,
            )
        if op.sha256 is not None and op.sha256 != art.sha256:
            raise InvalidRequestError(
                f"{where}{element}: sha256 {op.sha256} does not match the server's kernel "
                f"{op.name} {op.version} (sha256 {art.sha256})",
                element=element,
                line=op.line,
            )
        if art.stage != op.stage.value:
            raise InvalidRequestError(
                f"{where}{element}: kernel {op.name} {op.version} is a {art.stage} kernel, "
                f"not {op.stage.value}",
                element=element,
                line=op.line,
            )


def queue_message(
    s: Session, hub: Hub, robot_id: int, xml: str, msg: ControlMessage, actor: str, **detail: Any
) -> Message:
    """Check ``msg`` (parsed from ``xml``) for robot ``robot_id`` and queue it in ``s``'s transaction; the
    audit entries name ``actor`` (``operator:NAME``, ``rollout:ID``) and carry ``detail`` besides the
    message's number. Raises :class:`NotFoundError` for an unknown robot and :class:`InvalidRequestError`
    for a message the robot would refuse, before writing anything."""
    robot = s.get(Robot, robot_id)
    if robot is None:
        raise NotFoundError(f"no robot with id {robot_id}")
    check_operations(s, msg)
    check_like_robot(s, robot, msg)  # parameters and configuration, as the robot will check them
    seq = s.execute(
        update(Robot)
        .where(Robot.id == robot_id)
        .values(last_seq=Robot.last_seq + 1)
        .returning(Robot.last_seq)
    ).scalar_one_or_none()
    if seq is None:
        raise NotFoundError(f"no robot with id {robot_id}")
    m = Message(robot_id=robot_id, seq=seq, xml=xml, created_by=actor, status="queued")
    s.add(m)
    s.flush()
    target = f"robot:{robot_id}"
    entry = {"seq": seq, "bytes": len(xml.encode()), **detail}
    s.add(AuditEntry(actor=actor, action="message.post", target=target, detail=entry))
    for op in msg.operations:
        # the explicit override of the robot's anti-rollback floor (docs/reliability/supply-chain.md): the
        # only way a message may take a kernel below a version the robot has run
        if op.kind is OperationKind.ROLLBACK and op.below_floor:
            floor = {"seq": seq, "stage": op.stage.value, "kernel": f"{op.name}@{op.version}", **detail}
            s.add(AuditEntry(actor=actor, action="kernel.below_floor", target=target, detail=floor))
    hub.announce(s.connection(), f"messages:{robot_id}", seq)  # other processes hear it at commit
    return m
