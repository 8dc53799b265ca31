"""Static checks of an untrusted kernel module's source, with bounded nesting (no code of it runs).

:func:`source_problem` decodes the source, parses it (``ast.parse``), measures the syntax tree's nesting
depth iteratively and compiles the tree, turning every way this can fail on hostile input into one reason:
a syntax error, NUL bytes, not UTF-8, a ``RecursionError`` or ``MemoryError`` of the parser (deep
expressions such as ``((((...))))``, ``1+1+...+1`` or ``- - - ... 1``), or a tree nested deeper than
:data:`MAX_DEPTH`. Parsing itself can still take seconds and hundreds of MB on a pathological input of a few
hundred kB (CPython's parser and AST construction are linear but heavy), so the server runs this module as
a child process with CPU, memory and wall-time limits (:mod:`shared.kernels.source_check`); run as a
script it reads the source on stdin and writes one JSON object on stdout.

This module imports only the standard library (the child starts with ``python -I -S``). O(len(source)).
"""

from __future__ import annotations

import ast
import json
import sys
import warnings

__all__ = ["MAX_DEPTH", "main", "source_problem", "tree_depth"]

#: Deepest syntax tree accepted (nodes from the module down). Real kernels stay below ~30; CPython's
#: compiler itself gives up somewhere in the hundreds to thousands depending on the node kinds.
MAX_DEPTH = 100


def tree_depth(tree: ast.AST, limit: int) -> tuple[int, int | None]:
    """``(depth, line)``: the tree's nesting depth, counted iteratively (no recursion), stopping at the
    first node deeper than ``limit`` (then ``depth`` is ``limit + 1`` and ``line`` is that node's line)."""
    deepest, line = 0, None
    stack: list[tuple[ast.AST, int]] = [(tree, 1)]
    while stack:
        node, depth = stack.pop()
        if depth > deepest:
            deepest, line = depth, getattr(node, "lineno", line)
            if depth > limit:
                return depth, line
        stack.extend((child, depth + 1) for child in ast.iter_child_nodes(node))
    return deepest, line


def source_problem(
    source: bytes, filename: str = "<kernel>", max_depth: int = MAX_DEPTH
) -> dict[str, object]:
    """``{"ok": True}`` when ``source`` is UTF-8 Python that parses and compiles with a syntax tree at most
    ``max_depth`` deep; else ``{"ok": False, "reason": ..., "line": N or None}`` naming what was wrong and
    what is expected. Never raises for any input bytes."""
    try:
        text = source.decode("utf-8")
    except UnicodeDecodeError as exc:
        return _bad(f"not UTF-8 text (byte {exc.start}): expected a Python module encoded as UTF-8")
    if "\x00" in text:
        return _bad(f"contains a NUL byte (character {text.index(chr(0))}): expected Python source text")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # SyntaxWarning of odd literals: not the caller's business
        return _parse_and_compile(text, filename, max_depth)


def _parse_and_compile(text: str, filename: str, max_depth: int) -> dict[str, object]:
    try:
        tree = ast.parse(text, filename=filename)
    except SyntaxError as exc:  # IndentationError, "too many nested parentheses", ... included
        return _bad(f"not valid Python: line {exc.lineno}: {exc.msg}", exc.lineno)
    except (RecursionError, MemoryError, ValueError, OverflowError) as exc:
        return _bad(_too_complex(exc))
    depth, line = tree_depth(tree, max_depth)
    if depth > max_depth:
        return _bad(
            f"nested too deeply: the syntax tree is more than {max_depth} levels deep at line {line};"
            f" expected at most {max_depth} (split deep expressions into statements)",
            line,
        )
    try:
        compile(tree, filename, "exec", dont_inherit=True)
    except SyntaxError as exc:
        return _bad(f"not valid Python: line {exc.lineno}: {exc.msg}", exc.lineno)
    except (RecursionError, MemoryError, ValueError, OverflowError) as exc:
        return _bad(_too_complex(exc))
    return {"ok": True}


def _too_complex(exc: BaseException) -> str:
    return (
        f"too complex to parse ({type(exc).__name__}: {str(exc)[:80] or 'out of memory'}): expected"
        f" expressions nested at most {MAX_DEPTH} deep"
    )


def _bad(reason: str, line: int | None = None) -> dict[str, object]:
    return {"ok": False, "reason": reason, "line": line}


def main() -> None:
    """Child-process entry: ``argv[1]`` memory limit (bytes), ``argv[2]`` CPU limit (s); source on stdin."""
    try:
        import resource

        memory_bytes, cpu_s = int(sys.argv[1]), int(sys.argv[2])
        resource.setrlimit(resource.RLIMIT_AS, (memory_bytes, memory_bytes))
        resource.setrlimit(resource.RLIMIT_CPU, (cpu_s, cpu_s))
    except (ImportError, IndexError, ValueError, OSError):
        pass  # no limits where the platform has none; the parent's wall-time limit still holds
    out = source_problem(sys.stdin.buffer.read())
    sys.stdout.write(json.dumps(out))
    sys.stdout.flush()


if __name__ == "__main__":
    main()
