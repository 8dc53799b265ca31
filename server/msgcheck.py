"""Check a control message's settings on the server exactly as the robot will, before it is queued.

There is one validation: :func:`shared.control.to_config`, the function the robot agent applies messages
with (kernel parameters against each kernel's parameter model, the whole configuration against
:class:`~shared.pipeline.PipelineConfig`). The server runs it on the configuration the robot last reported
(the defaults before it reported one), so ``<epsilon>5000</epsilon>`` (50 m; at most 10 m) is a 422 naming
the parameter and its range instead of a message the robot refuses later.

Which kernels the server can build: the built-in ones (their code is the server's own). A kernel element
that resolves on the robot to an uploaded version (named by version, or without a version when the robot
holds or the message installs a newer one than the built-in) is left to the robot: the server holds only
the uploaded source, no parameter model it could use without running that code. A kernel that neither the
server's built-ins, the server's uploaded artifacts, the robot's reported store nor the message itself
provides cannot exist on the robot and is refused here.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable, Iterable, Mapping

from sqlalchemy import select
from sqlalchemy.orm import Session

from server.errors import InvalidRequestError
from server.models import KernelArtifact, Robot
from server.paramschema import parameter_problems
from shared.control import ControlMessage, ControlMessageError, KernelSpec, OperationKind, to_config
from shared.errors import LinemapError
from shared.kernels import REGISTRY, Stage
from shared.kernels.base import parse_version
from shared.kernels.stages import STAGES
from shared.pipeline.config import PipelineConfig

__all__ = [
    "builtin_only",
    "check_declared",
    "check_like_robot",
    "robot_checkable",
    "server_checkable",
    "uploaded_artifacts",
]

Version = tuple[int, int, int]


def _version(text: str | None) -> Version | None:
    if text is None:
        return None
    try:
        return parse_version(text)
    except ValueError:
        return None


def _builtin_versions() -> dict[tuple[str, str], set[Version]]:
    out: dict[tuple[str, str], set[Version]] = defaultdict(set)
    for info in REGISTRY.list():
        v = _version(info.version)
        if v is not None:
            out[(info.stage.value, info.name)].add(v)
    return out


def builtin_only(stage: Stage, name: str, version: str | None) -> bool:
    """Build a kernel here when it is built in at that version (at all, for no version); other kernels
    are the robot's to check."""
    versions = _builtin_versions().get((stage.value, name), set())
    return bool(versions) and (version is None or _version(version) in versions)


def server_checkable(
    artifacts: Iterable[KernelArtifact], msg: ControlMessage
) -> Callable[[Stage, str, str | None], bool]:
    """The ``checkable`` without a robot (``/control/xml``): built-in kernel versions are built here; a
    kernel name that is built in at another version, held uploaded (not deleted) or installed by ``msg``
    itself is the robot's to check; a name that exists nowhere is built here, which refuses it by name
    ("no kernel named ..."). O(artifacts)."""
    known = {(art.stage, art.name) for art in artifacts if art.deleted_at is None}
    known |= {key[0] for key in _builtin_versions().items()}
    for op in msg.operations:
        if op.kind in (OperationKind.INSTALL, OperationKind.UPDATE):
            known.add((op.stage.value, op.name))

    def checkable(stage: Stage, name: str, version: str | None) -> bool:
        return builtin_only(stage, name, version) or (stage.value, name) not in known

    return checkable


def uploaded_artifacts(s: Session) -> list[KernelArtifact]:
    """Every kernel artifact the server holds (deleted ones included). O(artifacts)."""
    return list(s.scalars(select(KernelArtifact)).all())


class _RobotKernels:
    """What the robot can resolve a kernel element to: built-ins, its reported store, the message's own
    installs, and (for a version named explicitly) any artifact the server ever held."""

    def __init__(self, builtin: dict[tuple[str, str], set[Version]]) -> None:
        self.builtin = builtin
        self.present: dict[tuple[str, str], set[Version]] = defaultdict(set)  # loaded on the robot
        self.known: dict[tuple[str, str], set[Version]] = defaultdict(set)  # could be on the robot

    def add(self, stage: str, name: str, version: str | None, *, present: bool) -> None:
        v = _version(version)
        if v is None:
            return
        self.known[(stage, name)].add(v)
        if present:
            self.present[(stage, name)].add(v)

    def __call__(self, stage: Stage, name: str, version: str | None) -> bool:
        key = (stage.value, name)
        builtin = self.builtin.get(key, set())
        if version is None:  # the robot takes the highest version it holds
            candidates = builtin | self.present.get(key, set())
            return not candidates or max(candidates) in builtin
        want = _version(version)
        if want in builtin:
            return True
        # an uploaded version the robot may hold: its parameters are the robot's to check; a version
        # nobody has is built here, which refuses it as the robot would ("has no version ...")
        return want not in self.known.get(key, set())


def robot_checkable(robot: Robot, artifacts: Iterable[KernelArtifact], msg: ControlMessage) -> _RobotKernels:
    """The ``checkable`` of :func:`shared.control.to_config` for messages queued to ``robot``."""
    kernels = _RobotKernels(_builtin_versions())
    reported = robot.kernels
    for k in reported or []:
        if isinstance(k, dict) and k.get("state") != "failed":
            kernels.add(str(k.get("stage")), str(k.get("name")), k.get("version"), present=True)
    for art in artifacts:
        # without a report, any live artifact may be installed on the robot
        present = reported is None and art.deleted_at is None
        kernels.add(art.stage, art.name, art.version, present=present)
    for op in msg.operations:
        if op.kind in (OperationKind.INSTALL, OperationKind.UPDATE):
            kernels.add(op.stage.value, op.name, op.version, present=True)
    return kernels


def _base_config(robot: Robot) -> PipelineConfig:
    if robot.config:
        try:
            return PipelineConfig.parse(robot.config)
        except LinemapError:
            pass  # a report this server cannot read: check against the defaults
    return PipelineConfig()


def check_like_robot(s: Session, robot: Robot, msg: ControlMessage) -> None:
    """Raise :class:`InvalidRequestError` (422) when the robot would refuse ``msg``'s settings, naming the
    element, the parameter and its allowed range. O(kernel artifacts + message)."""
    artifacts = uploaded_artifacts(s)
    kernels = robot_checkable(robot, artifacts, msg)
    try:
        to_config(msg, _base_config(robot), checkable=kernels)
        check_declared(artifacts, msg, kernels.present)
    except ControlMessageError as exc:
        raise InvalidRequestError(str(exc), element=exc.element, line=exc.line, reason=exc.reason) from None


def _specs(msg: ControlMessage) -> list[tuple[Stage, KernelSpec]]:
    out: list[tuple[Stage, KernelSpec]] = []
    for stage, spec in STAGES.items():
        given = getattr(msg, spec.field)
        for one in given if isinstance(given, tuple) else [given]:
            if isinstance(one, KernelSpec):
                out.append((stage, one))
    return out


def check_declared(
    artifacts: Iterable[KernelArtifact],
    msg: ControlMessage,
    present: Mapping[tuple[str, str], set[Version]] | None = None,
) -> None:
    """Check the parameters ``msg`` gives each uploaded kernel against the schema declared at its upload
    (:mod:`server.paramschema`); :class:`ControlMessageError` naming the parameter, its line and the
    kernel. The version checked is the one named, else the highest the robot holds (``present``) or the
    message installs, else the highest uploaded. Built-in versions were checked by building them."""
    live = [a for a in artifacts if a.deleted_at is None]
    installs = {
        (op.stage.value, op.name, op.version)
        for op in msg.operations
        if op.kind in (OperationKind.INSTALL, OperationKind.UPDATE)
    }
    for stage, spec in _specs(msg):
        if builtin_only(stage, spec.name, spec.version):
            continue
        mine = {a.version: a for a in live if a.stage == stage.value and a.name == spec.name}
        if spec.version is not None:
            art = mine.get(spec.version)
        else:
            held = set((present or {}).get((stage.value, spec.name), set()))
            for st, n, v in installs:
                parsed = _version(v)
                if st == stage.value and n == spec.name and parsed is not None:
                    held.add(parsed)
            pool = [a for v, a in mine.items() if _version(v) in held] or list(mine.values())
            art = max(pool, key=lambda a: _version(a.version) or (0, 0, 0), default=None)
        if art is None or art.parameters is None:
            continue
        problems = parameter_problems(art.parameters, spec.params_dict())
        if problems:
            param, reason = problems[0]
            given = param in dict(spec.params)
            raise ControlMessageError(
                f"invalid parameters for kernel '{spec.name}' {art.version} (as declared at its upload): "
                f"{param}: {reason}",
                element=f'<param name="{param}">' if given else f'<kernel name="{spec.name}">',
                line=spec.param_line(param) if given else spec.line,
            )
