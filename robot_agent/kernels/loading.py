"""Loading a downloaded kernel: importing its module and finding its kernel class. This is what
a confined worker process runs (:mod:`robot_agent.kernels.worker`); it is a plain function and can be used
in-process for trusted code (tests). A module's self-registration is undone, so loading never changes the
registry; errors name the line of the kernel's source where they were raised.
"""

from __future__ import annotations

import contextlib
import inspect
import sys
import threading
import types
from typing import Any

from robot_agent.errors import KernelRejected
from shared.errors import LinemapError
from shared.kernels import REGISTRY, Kernel, KernelRegistry, Stage
from shared.kernels.stages import STAGES

__all__ = ["describe_error", "load_kernel_class", "module_name", "source_file"]

#: Serialises module loads: the registry diff that undoes a module's self-registration needs it.
_LOAD_LOCK = threading.Lock()


def module_name(name: str, version: str) -> str:
    """The module name a kernel's source is imported under: ``linemap_kernel_<name>_<version>``.

    Characters other than letters, digits and ``_`` become ``_`` (``my-dbscan``, ``1.2.0`` ->
    ``linemap_kernel_my_dbscan_1_2_0``).
    """
    raw = f"linemap_kernel_{name}_{version}"
    return "".join(c if c.isalnum() or c == "_" else "_" for c in raw)


def source_file(stage: Stage | str, name: str, version: str) -> str:
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


def describe_error(exc: BaseException, filename: str) -> str:
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
    filename = source_file(want, name, version)
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
                raise KernelRejected(f"import failed: {describe_error(exc, filename)}") from None
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
