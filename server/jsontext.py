"""JSON text of plain data (dicts with string keys, lists, tuples, str, int, finite float, bool, None) for
what the server writes on an upload's path: the delta log's bodies (:mod:`server.maplog`), the undo records
(:mod:`server.maphistory`) and PostgreSQL's row parameters (:mod:`server.pgrows`).

pydantic-core's serialiser (Rust) writes the same JSON values as ``json.dumps(obj, separators=(",", ":"))``
(the reference its tests compare against; strings are written as UTF-8 where ``json.dumps`` escapes
non-ASCII, and exponents may be spelled differently, e.g. ``1e-7`` for ``1e-07``), about 10x faster on a
200-wall upload's event (0.11 against 1.1 ms): the encoding was 9 % of a loaded server's CPU
(``benchmarks/server_load.py`` under py-spy). O(size of ``obj``).
"""

from __future__ import annotations

from typing import Any

import pydantic_core

__all__ = ["dumps"]


def dumps(obj: Any) -> str:
    """Compact JSON text of ``obj`` (plain data, see the module docstring)."""
    return pydantic_core.to_json(obj).decode("utf-8")
