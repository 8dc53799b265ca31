"""``linemap kernels --describe FILE``: the description of the kernel a module file of one's own defines
(its stage, name, version and parameter JSON Schema), for the ``parameters`` field of its upload.

The file is imported in this process: it is the operator's own code on the operator's machine (the
server never runs uploaded code; the robot runs it only confined, after checking its signature). O(import).
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from typing import Any

from shared.errors import LinemapError

__all__ = ["describe_kernel_file"]


def describe_kernel_file(path: Path) -> dict[str, Any]:
    """``{stage, name, version, summary, parameters}`` of the one kernel class ``path`` defines;
    :class:`LinemapError` when the file cannot be imported or defines no kernel or several."""
    from shared.kernels.base import Kernel
    from shared.kernels.registry import KernelInfo

    if not path.is_file():
        raise LinemapError(f"{path}: no such file: expected a kernel module (.py)")
    modname = f"linemap_describe_{abs(hash(path.resolve()))}"
    spec = importlib.util.spec_from_file_location(modname, path)
    if spec is None or spec.loader is None:
        raise LinemapError(f"{path}: cannot be imported as a Python module")
    module = importlib.util.module_from_spec(spec)
    sys.modules[modname] = module
    try:
        spec.loader.exec_module(module)
    except Exception as exc:  # the operator's own file: say what went wrong in it
        raise LinemapError(f"{path}: importing it failed: {type(exc).__name__}: {exc}") from None
    finally:
        sys.modules.pop(modname, None)
    found = [
        obj
        for obj in vars(module).values()
        if isinstance(obj, type) and issubclass(obj, Kernel) and obj.__module__ == modname
    ]
    if len(found) != 1:
        names = ", ".join(c.__name__ for c in found) or "none"
        raise LinemapError(f"{path}: expected one kernel class defined in it, found {len(found)} ({names})")
    cls = found[0]
    doc = (cls.__doc__ or "").strip().splitlines()
    return KernelInfo(cls.stage, cls.name, cls.version, doc[0] if doc else "", cls).as_dict()
