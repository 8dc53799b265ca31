"""What a control message says (docs/design.md §6), as frozen dataclasses independent of its XML spelling.

Every field is optional: a message changes only what it mentions (``None`` = not mentioned). A kernel is
given by its registry name (``"dbscan"``, ``"hough"``), its parameters under the kernel's own names in SI
units (``epsilon_m`` in metres, whatever unit the XML used) and optionally a version. A kernel element fully
states that kernel: parameters it leaves out take the kernel's defaults, not the previous values, so a
message means the same whatever the robot ran before (messages are idempotent and safe to resend).

Source line numbers are kept for error messages but take no part in equality.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Literal

from shared.control.errors import ControlMessageError
from shared.kernels import Stage
from shared.pipeline.config import Mode

__all__ = [
    "NO_SCAN_MATCHING",
    "ControlMessage",
    "KernelOperation",
    "KernelSpec",
    "OperationKind",
    "ParamValue",
    "ScheduleEntry",
]

#: A kernel parameter's value as the message carries it (lengths are metres).
ParamValue = bool | int | float | str | tuple[int, ...]

#: ``ControlMessage.scan_matching`` value that switches scan matching off (``<scan-matching>none``).
NO_SCAN_MATCHING: Literal["none"] = "none"


@dataclass(frozen=True, slots=True)
class KernelSpec:
    """One kernel chosen by a message: registry ``name``, ``params`` (sorted by name), optional ``version``.

    ``line`` is the kernel element's line and ``param_lines`` each parameter's line (for errors only).
    """

    name: str
    params: tuple[tuple[str, ParamValue], ...] = ()
    version: str | None = None
    line: int | None = field(default=None, compare=False, repr=False)
    param_lines: tuple[tuple[str, int], ...] = field(default=(), compare=False, repr=False)

    def __post_init__(self) -> None:
        names = [name for name, _ in self.params]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ControlMessageError(f"parameter {dup[0]!r} given twice", element=f"<{self.name}>")
        object.__setattr__(self, "params", tuple(sorted(self.params, key=lambda kv: kv[0])))

    @classmethod
    def of(
        cls, name: str, params: Mapping[str, ParamValue] | None = None, version: str | None = None
    ) -> KernelSpec:
        """Convenience constructor from a mapping of parameters."""
        return cls(name, tuple((params or {}).items()), version)

    def params_dict(self) -> dict[str, ParamValue]:
        """The parameters as a plain dict (what :class:`shared.pipeline.KernelChoice` takes)."""
        return dict(self.params)

    def param_line(self, param: str) -> int | None:
        """Line of parameter ``param`` in the source document, if known."""
        return dict(self.param_lines).get(param)


@dataclass(frozen=True, slots=True)
class ScheduleEntry:
    """Mixed mode: stage ``stage`` runs ``mode`` (online/offline) with its own ``n_smax`` (None: default)."""

    stage: Stage
    mode: Mode
    n_smax: int | None = None
    line: int | None = field(default=None, compare=False, repr=False)


class OperationKind(StrEnum):
    """What a kernel operation does to the robot's kernel store (docs/design.md §7, §9)."""

    INSTALL = "install"
    UPDATE = "update"
    DELETE = "delete"
    ROLLBACK = "rollback"


@dataclass(frozen=True, slots=True)
class KernelOperation:
    """Install / update / delete / roll back kernel ``stage``/``name`` at ``version``.

    ``sha256`` (64 lower-case hex digits) identifies the artifact's exact bytes; required for install and
    update, optional for delete and rollback. ``below_floor`` (``below-floor="allow"``, rollback only) is
    the operator's explicit override of the robot's anti-rollback floor (docs/design.md §9,
    docs/reliability/supply-chain.md): without it no operation may take a kernel below a version the robot
    has run.
    """

    kind: OperationKind
    stage: Stage
    name: str
    version: str
    sha256: str | None = None
    line: int | None = field(default=None, compare=False, repr=False)
    below_floor: bool = False


@dataclass(frozen=True, slots=True)
class ControlMessage:
    """A parsed control message; ``None`` fields are not mentioned and keep the robot's current values.

    ``noise_removal`` is the whole chain in order (an empty tuple switches noise removal off);
    ``scan_matching`` may be :data:`NO_SCAN_MATCHING`; ``schedule`` (mixed mode) replaces the whole
    per-stage schedule; ``loop_closure`` (name ``"loop-closure"``, the settings of
    :class:`shared.slam.settings.LoopClosureSettings` as parameters) states loop closure whole, ``enabled``
    false switching it off; ``operations`` run in document order. ``lines`` maps top-level element names to
    their source lines (errors only).
    """

    seq: int | None = None
    mode: Mode | None = None
    n_smax: int | None = None
    heading_flush_deg: float | None = None
    segmentation: KernelSpec | None = None
    noise_removal: tuple[KernelSpec, ...] | None = None
    clustering: KernelSpec | None = None
    straight_line: KernelSpec | None = None
    scan_matching: KernelSpec | Literal["none"] | None = None
    schedule: tuple[ScheduleEntry, ...] | None = None
    loop_closure: KernelSpec | None = None
    operations: tuple[KernelOperation, ...] = ()
    lines: tuple[tuple[str, int], ...] = field(default=(), compare=False, repr=False)

    def line_of(self, element: str) -> int | None:
        """Source line of top-level element ``element`` (e.g. ``"n-smax"``), if known."""
        return dict(self.lines).get(element)
