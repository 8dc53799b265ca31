"""Making control messages ready on the poller's thread: parse, refuse downgrades, download each kernel the
message installs, verify its signature and run its checks in a confined worker process.

None of a downloaded kernel's code runs in the agent's process: the dry run and the conformance battery run
in a worker with time, CPU and memory limits (:mod:`robot_agent.kernels.dryrun`, docs/reliability/sandbox.md),
and a kernel that passed is served by a long-lived worker of its own. This may take seconds per kernel; the
mapping thread only gets the result (:class:`~robot_agent.control.Prepared`) through a queue.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

from robot_agent.control import Prepared, refuse_downgrades
from robot_agent.errors import AgentError, KernelRejected, LinkError
from robot_agent.link import ServerLink, is_transient
from robot_agent.models import KernelRecord
from robot_agent.settings import AgentSettings
from robot_agent.store import RobotDB
from shared.control import ControlMessageError, KernelOperation, OperationKind, parse_message
from shared.kernels import Kernel, Stage
from shared.types import Scan

__all__ = ["KernelLoader", "MessagePreparer"]

log = logging.getLogger(__name__)


class KernelLoader:
    """Starts the confined worker a downloaded kernel runs in, with the agent's limits (``kernel_memory_mb``,
    ``kernel_hang_s`` a call, ``dry_run_budget_s`` the import) and trusted keys."""

    def __init__(self, settings: AgentSettings, trusted: list[Ed25519PublicKey]) -> None:
        self.s = settings
        self.trusted = trusted

    def load(self, source: bytes, stage: Stage, name: str, version: str) -> type[Kernel[Any]]:
        """The class of a downloaded kernel running in its own confined worker process."""
        from robot_agent.kernels.dryrun import load_in_worker

        try:
            return load_in_worker(
                source,
                stage,
                name,
                version,
                memory_mb=self.s.kernel_memory_mb,
                call_s=self.s.kernel_hang_s,
                import_s=self.s.dry_run_budget_s,
            )
        except KernelRejected:
            raise
        except AgentError as exc:  # not the kernel's fault, but it cannot run: refused with the reason
            raise KernelRejected(f"could not start its worker process: {exc}") from None

    def load_stored(self, rec: KernelRecord) -> type[Kernel[Any]]:
        """A kernel of the Robot DB, its signature checked again (at start-up)."""
        from robot_agent.kernels.artifact import verify_artifact

        verify_artifact(rec.source, rec.sha256, rec.signature, self.trusted, self.s.allow_unsigned)
        return self.load(rec.source, Stage(rec.stage), rec.name, rec.version)


class MessagePreparer:
    """Collaborators: ``link`` (downloads), ``db`` (anti-rollback floors; each downloaded kernel's record),
    ``loader`` (workers and trusted keys), ``recent`` (the last scans, for dry runs)."""

    def __init__(
        self,
        settings: AgentSettings,
        link: ServerLink,
        db: RobotDB,
        loader: KernelLoader,
        recent: Callable[[], list[Scan]],
    ) -> None:
        self.s = settings
        self.link, self.db, self.loader = link, db, loader
        self._recent = recent

    def prepare(self, raw: dict[str, Any]) -> Prepared:
        """Parse a message and download/verify its kernels (network thread; may take seconds). A download
        that fails in transit (no answer, 408, 429, 5xx) raises :class:`LinkError`: the poller fetches the
        message again after a backoff instead of rejecting it for a network fault."""
        seq = int(raw["seq"])
        try:
            msg = parse_message(str(raw["xml"]).encode("utf-8"))
        except ControlMessageError as exc:
            return Prepared(seq, None, str(exc))
        prepared = Prepared(seq, msg)
        downgrade = refuse_downgrades(msg, self.db.run_floors())  # before downloading anything
        if downgrade is not None:
            prepared.error = downgrade
            return prepared
        installs = [op for op in msg.operations if op.kind in (OperationKind.INSTALL, OperationKind.UPDATE)]
        if not installs:
            return prepared
        self._verify_all(prepared, installs)
        return prepared

    def _verify_all(self, prepared: Prepared, installs: list[KernelOperation]) -> None:
        """Download and check each installed kernel of ``prepared``; the first refusal sets its error."""
        for op in installs:
            try:
                prepared.classes[(op.stage.value, op.name, op.version)] = self._fetch_and_verify(op)
            except KernelRejected as exc:
                prepared.error = f"<kernel-{op.kind.value}> {op.name} {op.version}: {exc.reason}"
                return
            except LinkError as exc:
                if is_transient(exc):
                    raise  # a network fault: the poller fetches the message again after a backoff
                prepared.error = f"<kernel-{op.kind.value}> {op.name} {op.version}: download failed: {exc}"
                return

    def _fetch_and_verify(self, op: KernelOperation) -> type[Kernel[Any]]:
        from robot_agent.kernels.artifact import verify_artifact
        from robot_agent.kernels.dryrun import verify_in_worker

        got = self.link.fetch_kernel(op.name, op.version)
        sha = op.sha256 or ""
        if got.stage and got.stage != op.stage.value:
            raise KernelRejected(
                f"the server has it as a {got.stage} kernel, the message says {op.stage.value}"
            )
        record = KernelRecord(
            stage=op.stage.value,
            name=op.name,
            version=op.version,
            sha256=sha,
            source=got.source,
            signature=got.signature,
            state="rejected",
        )
        try:
            record.key_id = verify_artifact(
                got.source, sha, got.signature, self.loader.trusted, self.s.allow_unsigned
            )
            # The kernel's code never runs in this process: the dry run and the conformance battery run in
            # a confined worker with time, CPU and memory limits (killed at them), and a kernel that passed
            # is served by a long-lived worker of its own.
            try:
                verify_in_worker(
                    got.source,
                    op.stage,
                    op.name,
                    op.version,
                    None,
                    self._recent(),
                    self.s.dry_run_budget_s,
                    conformance_s=self.s.dry_run_budget_s,
                )
            except KernelRejected:
                raise
            except AgentError as exc:  # the checks could not run: the kernel is not installed
                raise KernelRejected(f"its checks could not run: {exc}") from None
            cls = self.loader.load(got.source, op.stage, op.name, op.version)
        except KernelRejected as exc:
            record.reason = exc.reason
            self.db.save_kernel(record)
            raise
        record.state = "verified"
        self.db.save_kernel(record)
        return cls
