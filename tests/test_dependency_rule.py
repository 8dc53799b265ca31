"""The dependency rule of docs/architecture.md, checked on every import of the library.

Packages sit on layers; a module may import its own package and packages on lower layers, never a higher
or an equal one (two packages on one layer do not know each other). Imports inside functions count too:
a lazy import is still a dependency. The rule is read from the source (``ast``), nothing is imported.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

#: Layer of each package (a ``shared`` subpackage or top-level module of ``shared`` is its own package).
LAYERS: dict[str, int] = {
    "shared.errors": 0,
    "shared.types": 1,
    "shared.sqltypes": 1,
    "shared.signing": 1,
    "shared.protocol": 2,  # its pose-graph rows use shared.types
    "shared.stopsignals": 1,
    "shared.diskfull": 1,
    "shared.odometry": 2,
    "shared.metrics": 2,
    "shared.baselines": 2,
    "shared.io": 3,
    "shared.sim": 4,
    "shared.kernels": 5,
    "shared.pipeline": 6,
    "shared.slam": 7,
    "shared.control": 8,
    "shared.export": 8,
    "shared.mapping": 9,
    "shared.bench": 10,
    "shared.report": 11,
    "server": 12,
    "robot_agent": 12,
    "shared.foxbridge": 12,
    "shared.cli": 13,
}

#: Named exceptions, each with its reason: (importing package, imported module).
ALLOWED: dict[tuple[str, str], str] = {
    # the configuration validates the loop-closure settings it carries; both modules are leaves
    ("shared.pipeline", "shared.slam.settings"): "leaf settings model, imports only shared.slam.errors",
    ("shared.pipeline", "shared.slam.errors"): "leaf errors module",
}

PACKAGES = ("shared", "server", "robot_agent")


def package_of(module: str) -> str:
    """``shared.kernels.base`` -> ``shared.kernels``; ``server.app`` -> ``server``."""
    parts = module.split(".")
    if parts[0] == "shared" and len(parts) > 1:
        return f"shared.{parts[1]}"
    return parts[0]


def module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join(parts)


def imports(path: Path) -> list[tuple[int, str]]:
    """Every absolute import of the project's packages in ``path``: (line, module)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.append((node.lineno, node.module))
            # ``from shared import sim`` imports the subpackage
            if node.module == "shared":
                found += [(node.lineno, f"shared.{a.name}") for a in node.names]
    return [(line, m) for line, m in found if m.split(".")[0] in PACKAGES]


def library_files() -> list[Path]:
    return sorted(p for top in PACKAGES for p in (ROOT / top).rglob("*.py"))


def violations() -> list[str]:
    out: list[str] = []
    for path in library_files():
        src = package_of(module_name(path))
        for line, target in imports(path):
            dst = package_of(target)
            if dst == src or target == "shared":
                continue
            if (src, target) in ALLOWED:
                continue
            if src not in LAYERS or dst not in LAYERS:
                out.append(f"{path.relative_to(ROOT)}:{line}: {src} or {dst} has no layer in LAYERS")
            elif LAYERS[dst] >= LAYERS[src]:
                out.append(
                    f"{path.relative_to(ROOT)}:{line}: {src} (layer {LAYERS[src]}) imports {target} "
                    f"(layer {LAYERS[dst]}): only lower layers may be imported"
                )
    return out


def test_every_import_goes_down_the_layers() -> None:
    assert violations() == []


def test_every_package_has_a_layer() -> None:
    found = {package_of(module_name(p)) for p in library_files()}
    assert found - {"shared"} <= set(LAYERS), sorted(found - set(LAYERS))
    assert set(LAYERS) <= found, sorted(set(LAYERS) - found)


def test_the_architecture_document_states_the_same_layers() -> None:
    text = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    table = {m[2]: int(m[1]) for m in re.finditer(r"^\| (\d+) \| `([\w.]+)` \|", text, re.MULTILINE)}
    assert table == LAYERS


@pytest.mark.parametrize(
    ("src", "target", "ok"),
    [
        ("shared.kernels", "shared.types.scan", True),
        ("shared.kernels", "shared.pipeline.stages", False),
        ("server", "robot_agent.agent", False),
        ("robot_agent", "shared.cli.main", False),
        ("shared.pipeline", "shared.slam.settings", True),
        ("shared.pipeline", "shared.slam.mapper", False),
    ],
)
def test_the_rule_itself(src: str, target: str, ok: bool) -> None:
    dst = package_of(target)
    allowed = (src, target) in ALLOWED or LAYERS[dst] < LAYERS[src]
    assert allowed is ok
