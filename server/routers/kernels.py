"""``/kernels`` and ``/keys``: signed kernel artifacts (immutable versions) and the keys that may sign them.

An upload is a Python module file plus its name, stage, version and an Ed25519 signature over its SHA-256
(:mod:`shared.signing`). The server checks what it can without running the code: the name and version
spelling (one spelling per version number: :mod:`shared.kernels.versions`), the stage, the size, UTF-8
Python that parses and compiles with bounded nesting (checked in a child process with time and memory
limits: :mod:`shared.kernels.source_check`), and that a registered key signed it. Running the kernel
is the robot's business (it verifies again and dry-runs it before swapping it in).
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, File, Form, Request, Response, UploadFile, status
from fastapi.concurrency import run_in_threadpool
from sqlalchemy import select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from server.audit import record
from server.deps import AppState, OperatorDep, Principal, PrincipalDep, StateDep
from server.errors import ConflictError, GoneError, InvalidRequestError, NotFoundError, TooLargeError
from server.models import KernelArtifact, SigningKey, utcnow
from server.paramschema import read_declared_schema
from server.schemas import KernelOut, SigningKeyIn, SigningKeyOut
from shared.errors import KernelSourceError
from shared.kernels import Stage
from shared.kernels.source_check import check_source_bounded
from shared.kernels.versions import legacy_version_key, parse_version
from shared.protocol import (
    ARTIFACT_KEY_ID_HEADER,
    ARTIFACT_SHA256_HEADER,
    ARTIFACT_SIGNATURE_HEADER,
    ARTIFACT_STAGE_HEADER,
    KERNEL_NAME_MAX_LENGTH,
    KERNEL_NAME_RE,
)
from shared.signing import SignatureError, key_id, load_public_key, public_key_text, sha256_hex, verify_digest

__all__ = ["keys_router", "router"]

router = APIRouter(prefix="/kernels", tags=["kernels"])
keys_router = APIRouter(prefix="/keys", tags=["keys"])

_STAGES = [s.value for s in Stage]


def _kernel_out(k: KernelArtifact) -> KernelOut:
    return KernelOut(
        name=k.name,
        version=k.version,
        stage=k.stage,
        sha256=k.sha256,
        size_bytes=k.size_bytes,
        signature=k.signature,
        key_id=k.key_id,
        uploaded_at=k.uploaded_at,
        uploaded_by=k.uploaded_by,
        deleted=k.deleted_at is not None,
        parameters=k.parameters,
    )


def _key_out(k: SigningKey) -> SigningKeyOut:
    return SigningKeyOut(
        key_id=k.key_id,
        name=k.name,
        public_key=k.public_key,
        created_at=k.created_at,
        revoked=k.revoked_at is not None,
    )


# --- keys -------------------------------------------------------------------------------------------


@keys_router.post("", status_code=status.HTTP_201_CREATED, response_model=SigningKeyOut)
def add_key(body: SigningKeyIn, who: OperatorDep, state: StateDep) -> SigningKeyOut:
    """Trust an Ed25519 public key for kernel signatures (``linemap keys generate`` makes one)."""
    try:
        public = load_public_key(body.public_key)
    except SignatureError as exc:
        raise InvalidRequestError(str(exc), field="public_key") from None
    kid = key_id(public)
    try:
        with state.db.session() as s:
            key = SigningKey(key_id=kid, name=body.name, public_key=public_key_text(public))
            s.add(key)
            s.flush()
            record(s, who, "key.add", f"key:{kid}", name=body.name)
            return _key_out(key)
    except IntegrityError:
        raise ConflictError(f"key {kid} is registered already") from None


@keys_router.get("", response_model=list[SigningKeyOut])
def list_keys(who: PrincipalDep, state: StateDep) -> list[SigningKeyOut]:
    with state.db.read() as s:
        return [_key_out(k) for k in s.scalars(select(SigningKey).order_by(SigningKey.id))]


@keys_router.delete("/{kid}", status_code=status.HTTP_204_NO_CONTENT)
def revoke_key(kid: str, who: OperatorDep, state: StateDep) -> None:
    """Stop accepting new uploads signed by this key (kernels already uploaded stay)."""
    with state.db.session() as s:
        key = s.scalars(select(SigningKey).where(SigningKey.key_id == kid)).first()
        if key is None:
            raise NotFoundError(f"no key {kid}")
        if key.revoked_at is None:
            key.revoked_at = utcnow()
            record(s, who, "key.revoke", f"key:{kid}")


# --- kernels ----------------------------------------------------------------------------------------


def _validate(name: str, stage: str, version: str, source: bytes, limit: int) -> None:
    if not KERNEL_NAME_RE.fullmatch(name) or len(name) > KERNEL_NAME_MAX_LENGTH:
        raise InvalidRequestError(
            f"name {name[:80]!r}: expected lower-case words joined by '-', e.g. 'my-dbscan'", field="name"
        )
    if stage not in _STAGES:
        raise InvalidRequestError(
            f"stage {stage[:40]!r}: expected one of {', '.join(_STAGES)}", field="stage"
        )
    try:
        parse_version(version)
    except ValueError as exc:
        raise InvalidRequestError(str(exc), field="version") from None
    if len(source) > limit:
        raise TooLargeError(f"kernel file of {len(source)} bytes; the limit is {limit}")
    if not source:
        raise InvalidRequestError("file: the kernel module is empty", field="file")


def _check_source(name: str, version: str, source: bytes) -> None:
    """422 unless module ``name`` ``version`` parses and compiles with bounded nesting, time and memory
    (in a child process: :mod:`shared.kernels.source_check`); pathological source never reaches this
    process's parser."""
    try:
        check_source_bounded(source)
    except KernelSourceError as exc:
        raise InvalidRequestError(f"file: {exc.reason}", field="file", line=exc.line) from None


def _signer(s: Session, digest: str, signature: str) -> str:
    keys = list(s.scalars(select(SigningKey).where(SigningKey.revoked_at.is_(None))))
    if not keys:
        raise InvalidRequestError("no signing key is registered: POST /api/v1/keys first", field="signature")
    for k in keys:
        try:
            verify_digest(load_public_key(k.public_key), digest, signature)
        except SignatureError as exc:
            if "does not verify" not in str(exc):
                raise InvalidRequestError(str(exc), field="signature") from None
            continue
        return k.key_id
    names = ", ".join(k.key_id for k in keys)
    raise InvalidRequestError(
        f"signature does not verify for sha256 {digest} with any registered key ({names})", field="signature"
    )


def _refuse_same_number(s: Session, name: str, version: str) -> None:
    """409 if another stored version of ``name`` (deleted ones too: versions are never reused) is the same
    number triple spelled differently, e.g. ``01.0.0`` stored before the canonical spelling was enforced.
    O(versions of ``name``)."""
    wanted = parse_version(version)
    for row in s.execute(
        select(KernelArtifact.version, KernelArtifact.sha256).where(KernelArtifact.name == name)
    ):
        if row.version != version and legacy_version_key(row.version) == wanted:
            raise ConflictError(
                f"kernel {name} {version} is the same version as the stored {name} {row.version}"
                f" (sha256 {row.sha256}); versions are immutable: upload a new, higher version",
                sha256=row.sha256,
                existing=row.version,
            )


def _store(
    state: AppState,
    who: Principal,
    name: str,
    stage: str,
    version: str,
    source: bytes,
    signature: str,
    parameters: dict[str, Any] | None,
) -> tuple[KernelOut, bool]:
    digest = sha256_hex(source)
    with state.db.session() as s:
        existing = s.scalars(
            select(KernelArtifact).where(KernelArtifact.name == name, KernelArtifact.version == version)
        ).first()
        if existing is not None:
            if existing.sha256 == digest and existing.deleted_at is None:
                return _kernel_out(existing), False  # the same upload again
            raise ConflictError(
                f"kernel {name} {version} exists already (sha256 {existing.sha256}); versions are immutable: "
                "upload a new version",
                sha256=existing.sha256,
            )
        _refuse_same_number(s, name, version)
        other = s.scalars(select(KernelArtifact.stage).where(KernelArtifact.name == name)).first()
        if other is not None and other != stage:
            raise ConflictError(f"kernel {name} is a {other} kernel; a new version cannot change its stage")
        kid = _signer(s, digest, signature)
        art = KernelArtifact(
            name=name,
            version=version,
            stage=stage,
            sha256=digest,
            size_bytes=len(source),
            source=source,
            signature=signature,
            key_id=kid,
            uploaded_by=who.actor,
            parameters=parameters,
        )
        s.add(art)
        s.flush()
        record(s, who, "kernel.upload", f"kernel:{name}@{version}", stage=stage, sha256=digest, key_id=kid)
        return _kernel_out(art), True


@router.post("", status_code=status.HTTP_201_CREATED, response_model=KernelOut)
async def upload_kernel(
    who: OperatorDep,
    state: StateDep,
    response: Response,
    file: Annotated[UploadFile, File(description="The kernel's Python module.")],
    name: Annotated[str, Form()],
    stage: Annotated[str, Form(description=f"One of {', '.join(_STAGES)}.")],
    version: Annotated[str, Form(description="MAJOR.MINOR.PATCH")],
    signature: Annotated[str, Form(description="Base64 Ed25519 signature over the file's SHA-256.")],
    parameters: Annotated[
        str | None,
        Form(
            description="Optional: the kernel's parameters as a JSON Schema (`linemap kernels describe FILE` "
            "prints it); messages choosing this kernel are then checked against it before they are queued."
        ),
    ] = None,
) -> KernelOut:
    """Upload a signed kernel version (201; 200 when the identical artifact is there already)."""
    limit = state.settings.max_kernel_bytes
    source = await file.read(limit + 1)
    _validate(name, stage, version, source, limit)
    declared = read_declared_schema(parameters)
    await run_in_threadpool(_check_source, name, version, source)
    out, created = await run_in_threadpool(
        _store, state, who, name, stage, version, source, signature.strip(), declared
    )
    if not created:
        response.status_code = status.HTTP_200_OK
    return out


@router.get("", response_model=list[KernelOut])
def list_kernels(
    who: PrincipalDep,
    state: StateDep,
    name: str | None = None,
    stage: str | None = None,
    deleted: bool = False,
) -> list[KernelOut]:
    """Uploaded kernels, newest first; ``deleted=true`` includes deleted versions."""
    q = select(KernelArtifact).order_by(KernelArtifact.name, KernelArtifact.id.desc())
    if name is not None:
        q = q.where(KernelArtifact.name == name)
    if stage is not None:
        q = q.where(KernelArtifact.stage == stage)
    if not deleted:
        q = q.where(KernelArtifact.deleted_at.is_(None))
    with state.db.read() as s:
        return [_kernel_out(k) for k in s.scalars(q)]


@router.get("/builtin")
def builtin_kernels(who: PrincipalDep) -> list[dict[str, Any]]:
    """The kernels every robot has built in, with their parameters' JSON Schemas (units, ranges, defaults)."""
    from shared.kernels import REGISTRY

    return REGISTRY.describe()


@router.get("/stages")
def stages(who: PrincipalDep) -> list[dict[str, Any]]:
    """The pipeline's stages in processing order, as the stage descriptions state them
    (``shared.kernels.stages``): name, paper section, configuration field, control-message element, result
    type, and whether a stage chains several kernels, may be switched off, or follows the schedule."""
    from shared.kernels.stages import STAGES

    return [spec.as_dict() for spec in STAGES.values()]


def _find(s: Session, name: str, version: str) -> KernelArtifact:
    art = s.scalars(
        select(KernelArtifact).where(KernelArtifact.name == name, KernelArtifact.version == version)
    ).first()
    if art is None:
        raise NotFoundError(f"no kernel {name} {version}")
    return art


@router.get("/{name}/{version}", response_model=KernelOut)
def read_kernel(name: str, version: str, who: PrincipalDep, state: StateDep) -> KernelOut:
    with state.db.read() as s:
        return _kernel_out(_find(s, name, version))


@router.get(
    "/{name}/{version}/artifact",
    response_class=Response,
    responses={200: {"content": {"text/x-python": {}}}, 304: {"description": "ETag matched"}},
)
def fetch_artifact(name: str, version: str, request: Request, who: PrincipalDep, state: StateDep) -> Response:
    """The module file itself; ``ETag`` is its sha256, signature and key id come in headers."""
    with state.db.read() as s:
        art = _find(s, name, version)
        if art.deleted_at is not None or art.source is None:
            raise GoneError(f"kernel {name} {version} was deleted")
        etag = f'"{art.sha256}"'
        headers = {
            "ETag": etag,
            ARTIFACT_SHA256_HEADER: art.sha256,
            ARTIFACT_SIGNATURE_HEADER: art.signature,
            ARTIFACT_KEY_ID_HEADER: art.key_id,
            ARTIFACT_STAGE_HEADER: art.stage,
            "Cache-Control": "private, max-age=31536000, immutable",
        }
        if etag in [t.strip() for t in request.headers.get("if-none-match", "").split(",")]:
            return Response(status_code=status.HTTP_304_NOT_MODIFIED, headers=headers)
        return Response(art.source, media_type="text/x-python", headers=headers)


@router.delete("/{name}/{version}", status_code=status.HTTP_204_NO_CONTENT)
def delete_kernel(name: str, version: str, who: OperatorDep, state: StateDep) -> None:
    """Delete a version's code; its name and version stay taken (versions are never reused)."""
    with state.db.session() as s:
        art = _find(s, name, version)
        if art.deleted_at is None:
            art.deleted_at, art.source = utcnow(), None
            record(s, who, "kernel.delete", f"kernel:{name}@{version}", sha256=art.sha256)
