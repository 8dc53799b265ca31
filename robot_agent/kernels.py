"""Checks a downloaded kernel passes before the agent may run it (docs/design.md §7, §9).

The agent installs a kernel only after every step below succeeded, cheapest first; each refusal raises
:class:`~robot_agent.errors.KernelRejected` whose ``reason`` is what the server (and the operator) is told:

1. :func:`verify_artifact`: the SHA-256 of the source matches the message's, and an Ed25519 signature by a
   key the robot trusts covers it (unsigned code only with the ``--allow-unsigned`` development flag);
2. the dry run and the conformance battery, in a confined worker process with time, CPU and memory limits
   (:func:`robot_agent.dryrun.verify_in_worker`; :func:`dry_run` is its dry-run part);
3. the kernel is then loaded in a long-lived worker process of its own (:func:`robot_agent.dryrun.
   load_in_worker`), and the agent registers a class that forwards every call to it.

The downloaded code never runs in the agent's process. :func:`load_kernel_class` (importing a module and
finding its kernel class) and :func:`check_conformance` are what the worker runs; they are plain functions
and can be used in-process for trusted code (tests). Nothing here touches the database or the network.
"""

from __future__ import annotations

import contextlib
import inspect
import sys
import threading
import types
from collections.abc import Mapping, Sequence
from typing import Any

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PublicKey

from robot_agent.errors import KernelRejected
from shared.errors import LinemapError
from shared.kernels import (
    REGISTRY,
    Kernel,
    KernelRegistry,
    Stage,
)
from shared.kernels.conformance import check_kernel
from shared.kernels.stages import STAGES
from shared.signing import SignatureError, key_id, sha256_hex, verify_digest

__all__ = [
    "STARTUP_ALLOWANCE_S",
    "DryRunReport",
    "check_conformance",
    "dry_run",
    "load_kernel_class",
    "module_name",
    "verify_artifact",
]


#: Serialises module loads: the registry diff that undoes a module's self-registration needs it.
_LOAD_LOCK = threading.Lock()

_UNSIGNED = "unsigned kernel refused; run the agent with --allow-unsigned for development"


# --------------------------------------------------------------------------------------- 1. the artifact
def verify_artifact(
    source: bytes,
    sha256: str,
    signature: str | None,
    trusted: Sequence[Ed25519PublicKey],
    allow_unsigned: bool = False,
) -> str | None:
    """Check a kernel artifact's digest and signature; return the id of the key that signed it.

    ``sha256`` is the hex digest the control message names, ``signature`` the base64 Ed25519 signature over
    it (:func:`shared.signing.sign_digest`), ``trusted`` the public keys this robot accepts. Returns the
    signing key's id, or ``None`` for unsigned code accepted because ``allow_unsigned`` is set (development
    only). A signature that is present is always checked, even with ``allow_unsigned``.

    Raises :class:`KernelRejected`: "sha256 mismatch: expected X, got Y"; "unsigned kernel refused; ...";
    no trusted keys configured; a signature that is malformed or verifies with none of the keys.
    O(len(source)) for the hash, then ~0.1 ms per trusted key.
    """
    got = sha256_hex(source)
    if got != sha256.strip().lower():
        raise KernelRejected(f"sha256 mismatch: expected {sha256}, got {got}")
    if not signature:
        if allow_unsigned:
            return None
        raise KernelRejected(_UNSIGNED)
    if not trusted:
        raise KernelRejected(
            "signed kernel refused: this robot trusts no signing key; add the operator's public key"
            " (linemap keys generate prints it) to the agent's trusted keys"
        )
    failures: list[str] = []
    for key in trusted:
        try:
            verify_digest(key, got, signature)
        except SignatureError as exc:
            failures.append(str(exc))
            continue
        return key_id(key)
    if any(not f.startswith("signature does not verify") for f in failures):
        malformed = next(f for f in failures if not f.startswith("signature does not verify"))
        raise KernelRejected(f"bad signature: {malformed}")
    ids = ", ".join(key_id(k) for k in trusted)
    raise KernelRejected(f"bad signature: it verifies with none of the trusted keys ({ids})")


# ------------------------------------------------------------------------------------------ 2. loading
def module_name(name: str, version: str) -> str:
    """The module name a kernel's source is imported under: ``linemap_kernel_<name>_<version>``.

    Characters other than letters, digits and ``_`` become ``_`` (``my-dbscan``, ``1.2.0`` ->
    ``linemap_kernel_my_dbscan_1_2_0``).
    """
    raw = f"linemap_kernel_{name}_{version}"
    return "".join(c if c.isalnum() or c == "_" else "_" for c in raw)


def _source_file(stage: Stage | str, name: str, version: str) -> str:
    return f"<kernel {stage}/{name}@{version}>"


def _stage(stage: Stage | str) -> Stage:
    try:
        return Stage(stage)
    except ValueError:
        known = ", ".join(s.value for s in Stage)
        raise KernelRejected(f"unknown stage {stage!r}: expected one of {known}") from None


def _line_in(exc: BaseException, filename: str) -> int | None:
    """The line of the kernel source (``filename``) where ``exc`` was raised, innermost first."""
    if isinstance(exc, SyntaxError) and exc.filename == filename:
        return exc.lineno
    line = None
    tb = exc.__traceback__
    while tb is not None:
        if tb.tb_frame.f_code.co_filename == filename:
            line = tb.tb_lineno
        tb = tb.tb_next
    return line


def _describe(exc: BaseException, filename: str) -> str:
    """``"ExcType: message (line N)"`` with N the innermost line of the kernel's own source, if any."""
    message = exc.msg if isinstance(exc, SyntaxError) else str(exc)
    line = _line_in(exc, filename)
    where = f" (line {line})" if line is not None else ""
    return f"{type(exc).__name__}: {message}{where}"


def _ident(cls: type[Any]) -> str:
    return f"{getattr(cls, 'stage', '?')}/{getattr(cls, 'name', cls.__name__)}@{getattr(cls, 'version', '?')}"


def _undo_registrations(before: dict[tuple[Stage, str, str], type[Kernel[Any]]], modname: str) -> None:
    """Undo what executing module ``modname`` did to the global registry.

    Removes every class the module registered (its ``__module__`` is ``modname``) and puts back any
    built-in (a class from ``shared``) it removed. Entries of other downloaded kernels are left alone, so a
    registration or deletion the agent makes meanwhile from another thread is never reverted.
    """
    for info in list(REGISTRY):
        key = (info.stage, info.name, info.version)
        if info.cls.__module__ == modname and before.get(key) is not info.cls:
            REGISTRY.unregister(*key)
    now = {(i.stage, i.name, i.version): i.cls for i in REGISTRY}
    for key, cls in before.items():
        if cls.__module__.startswith("shared.") and now.get(key) is not cls:
            with contextlib.suppress(LinemapError):
                REGISTRY.register(cls)


def load_kernel_class(source: bytes, stage: Stage | str, name: str, version: str) -> type[Kernel[Any]]:
    """Import a kernel's source in a fresh module and return its kernel class for ``stage/name@version``.

    The module is compiled and executed in its own namespace named :func:`module_name`; it stays in
    ``sys.modules`` on success (pydantic parameter models and dataclasses resolve annotations through it;
    a previous module of the same name is replaced) and is removed on any failure (the previous one is
    put back). The module must define exactly one concrete :class:`Kernel` subclass of the stage's base
    with the requested stage, name and version; its declaration is checked as ``REGISTRY.register`` would.
    Nothing is left in the global :data:`REGISTRY`: registrations the module made (``@register``) are
    undone, built-ins it removed are put back; the agent registers the class after every check passed.
    Loads are serialised by a lock; safe to call from a thread other than the step loop's.

    Raises :class:`KernelRejected`: "import failed: <ExcType>: msg (line N)" for any exception (syntax
    error, missing import, ``sys.exit``) while executing the module; no or several matching classes (naming
    the kernels found); a class that subclasses the wrong stage base or declares itself badly.
    Cost: that of importing the module.
    """
    want = _stage(stage)
    filename = _source_file(want, name, version)
    modname = module_name(name, version)
    with _LOAD_LOCK:
        previous = sys.modules.get(modname)
        module = types.ModuleType(modname, f"Downloaded kernel {want}/{name}@{version}")
        module.__file__ = filename
        before = {(i.stage, i.name, i.version): i.cls for i in REGISTRY}
        sys.modules[modname] = module
        ok = False
        try:
            try:
                code = compile(source, filename, "exec", dont_inherit=True)
                exec(code, module.__dict__)
            except (Exception, SystemExit) as exc:
                raise KernelRejected(f"import failed: {_describe(exc, filename)}") from None
            finally:
                _undo_registrations(before, modname)
            cls = _find_kernel(module, want, name, version)
            ok = True
            return cls
        finally:
            if not ok:
                if previous is not None:
                    sys.modules[modname] = previous
                else:
                    sys.modules.pop(modname, None)


def _find_kernel(module: types.ModuleType, stage: Stage, name: str, version: str) -> type[Kernel[Any]]:
    found = [
        obj
        for obj in vars(module).values()
        if isinstance(obj, type)
        and issubclass(obj, Kernel)
        and obj.__module__ == module.__name__
        and not inspect.isabstract(obj)
    ]
    wanted = f"{stage}/{name}@{version}"
    matches = [
        c
        for c in found
        if getattr(c, "stage", None) == stage
        and getattr(c, "name", None) == name
        and getattr(c, "version", None) == version
    ]
    if len(matches) != 1:
        listed = ", ".join(sorted(_ident(c) for c in found)) or "no kernel class"
        how = "no" if not matches else f"{len(matches)} classes for"
        raise KernelRejected(f"the module defines {how} kernel {wanted}: found {listed}")
    cls = matches[0]
    base = STAGES[stage].base
    if not issubclass(cls, base):
        raise KernelRejected(f"kernel {wanted} ({cls.__name__}) must subclass {base.__name__}")
    try:
        KernelRegistry().register(cls)  # the registry's declaration checks, on a throw-away registry
    except LinemapError as exc:
        raise KernelRejected(f"invalid kernel declaration: {exc}") from None
    return cls


# -------------------------------------------------------------------------------------- 3. conformance
def check_conformance(cls: type[Kernel[Any]], params: Mapping[str, Any] | None = None) -> None:
    """Run :func:`shared.kernels.conformance.check_kernel`; :class:`KernelRejected` listing the problems.

    The reason names at most 10 problems (and how many more there were). About 12 ``apply`` calls on at
    most 1000 points, in the calling process.
    """
    problems = check_kernel(cls, params)
    if problems:
        shown = "; ".join(problems[:10])
        more = f"; and {len(problems) - 10} more" if len(problems) > 10 else ""
        n = len(problems)
        raise KernelRejected(
            f"conformance failed for {_ident(cls)} ({n} problem{'s' if n > 1 else ''}): {shown}{more}"
        )


from robot_agent.dryrun import (  # noqa: E402  (kept importable from here)
    STARTUP_ALLOWANCE_S,
    DryRunReport,
    dry_run,
)
