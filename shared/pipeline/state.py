"""A mapper's learned state as data (docs/design.md §7): what a pipeline or a pose graph holds after its last
step, as a frozen :class:`MapperState` of plain values and numpy arrays, and its compact bytes form.

The tree is built by walking the mapper's objects: plain values, lists, tuples, dicts, deques, numpy arrays
and scalars, enums, kernels (by registry name, version and parameters) and objects of the classes
registered with :func:`register_state_class` (their ``__dict__`` and ``__slots__``). An object met twice is
written once and referred to after, so objects shared inside the mapper stay shared after a restore.

The bytes form (:meth:`MapperState.to_bytes`) is compressed JSON for the tree and the arrays' raw bytes
(numbers only, never pickles). Reading it never runs code: classes are looked up in the registry by name
(never imported), built with ``object.__new__`` and their attributes set. A blob of another format
version, or one that does not parse, is refused with :class:`~shared.errors.StateError` naming what was wrong.

Cost: O(state size) both ways; a 100-wall map with a 2,000-pose trajectory is about 10 ms and 200 kB.
"""

from __future__ import annotations

import json
import zlib
from collections import deque
from dataclasses import dataclass
from enum import Enum
from typing import Any

import numpy as np

from shared.errors import StateError
from shared.kernels import REGISTRY, Stage
from shared.kernels.base import Kernel

__all__ = ["STATE_FORMAT", "MapperState", "decode_tree", "encode_tree", "register_state_class"]

#: the bytes form's version; a reader refuses any other. It names the layout too (the classes kept and
#: their attributes): a change to what a state holds comes with a new format, so an older agent's state
#: is refused with an error that says so, never half read (tests/shared/slam/test_onlinestate.py pins it).
#: 2: the graph mapper's pending jobs, its solver's history and its per-step rows (2026-12-06)
#: 3: places (retired keyframes and kept scans, shared.slam.places), the keyframes' rows, the pose graph's
#: estimate and edges as arrays (2026-12-06)
#: 4: the pose graph's riders (retired keyframes carried by a newer node, shared.slam.riders) (2026-12-07)
#: 5: each closure's covariance and each pending search's closure count (shared.slam.window) (2026-12-07)
STATE_FORMAT = 6
#: the bytes form starts with this, then the zlib-compressed archive
_MAGIC = b"LMSTATE\x00"

_CLASSES: dict[str, type] = {}


def register_state_class(*classes: type) -> None:
    """Allow objects of ``classes`` in a mapper's state (their attributes are written as they are)."""
    for cls in classes:
        _CLASSES[f"{cls.__module__}.{cls.__qualname__}"] = cls


@dataclass(frozen=True, slots=True)
class MapperState:
    """A mapper's state: ``kind`` (``"pipeline"`` or ``"graph"``), the object tree (JSON-able), and the
    arrays it refers to by index. Pure data; :meth:`to_bytes` / :meth:`from_bytes` are the stored form."""

    kind: str
    tree: Any
    arrays: tuple[np.ndarray, ...]
    format: int = STATE_FORMAT

    def to_bytes(self) -> bytes:
        """A magic prefix, then zlib (level 1) over: the header's length (8 bytes, little endian), the
        header (JSON: format, kind, tree, and each array's dtype, shape and byte count) and the arrays'
        bytes one after another. The grids of cells seen free are mostly empty: about a tenth of the raw
        size, at a few milliseconds a megabyte."""
        table = [[a.dtype.str, list(a.shape), a.nbytes] for a in self.arrays]
        head = json.dumps({"format": self.format, "kind": self.kind, "tree": self.tree, "arrays": table})
        raw = head.encode()
        body = b"".join([len(raw).to_bytes(8, "little"), raw, *(a.tobytes() for a in self.arrays)])
        return _MAGIC + zlib.compress(body, 1)

    @classmethod
    def from_bytes(cls, data: bytes) -> MapperState:
        """Parse :meth:`to_bytes`' form; :class:`StateError` if it is not that form or another version."""
        if not data.startswith(_MAGIC):
            raise StateError("the mapping state is not a linemap mapper state (its first bytes are wrong)")
        try:
            body = zlib.decompress(data[len(_MAGIC) :])
            size = int.from_bytes(body[:8], "little")
            head = json.loads(body[8 : 8 + size].decode())
        except (zlib.error, ValueError) as exc:
            raise StateError(f"the mapping state does not parse ({type(exc).__name__}: {exc})") from None
        if not isinstance(head, dict) or not isinstance(head.get("format"), int):
            raise StateError("the mapping state's header has no format version")
        if head["format"] != STATE_FORMAT:
            raise StateError(
                f"the mapping state has format {head['format']}: this agent reads format {STATE_FORMAT}"
            )
        if not isinstance(head.get("kind"), str) or not isinstance(head.get("arrays"), list):
            raise StateError("the mapping state's header has no kind or no array table")
        arrays, at = [], 8 + size
        for entry in head["arrays"]:
            arrays.append(_array(body, at, entry))
            at += int(entry[2])
        if at != len(body):
            raise StateError(f"the mapping state has {len(body) - at} bytes beyond its arrays: expected none")
        return cls(head["kind"], head.get("tree"), tuple(arrays), head["format"])


def _array(body: bytes, at: int, entry: Any) -> np.ndarray:
    """One array of the body at byte ``at``, as the table ``entry`` [dtype, shape, bytes] describes it."""
    try:
        dtype_str, shape_list, nbytes = entry
        dtype = np.dtype(dtype_str)
        if dtype.kind not in "biufc":
            raise StateError(f"the mapping state has an array of dtype {dtype_str}: only numbers are kept")
        shape = tuple(int(n) for n in shape_list)
        count = int(np.prod(shape, dtype=np.int64))
        if count * dtype.itemsize != nbytes or at + nbytes > len(body):
            raise StateError(f"the mapping state's array {shape} {dtype_str} does not fit its {nbytes} bytes")
        return np.frombuffer(body, dtype=dtype, count=count, offset=at).reshape(shape)
    except StateError:
        raise
    except (TypeError, ValueError) as exc:
        raise StateError(f"the mapping state's array table does not parse ({exc})") from None


# ---------------------------------------------------------------------------------------------- encoding
class _Encoder:
    def __init__(self, skip: dict[type, frozenset[str]]) -> None:
        self.arrays: list[np.ndarray] = []
        self._seen: dict[int, int] = {}
        self._keep: list[Any] = []  # keeps encoded objects alive, so their ids stay unique
        self._skip = skip

    def node(self, value: Any) -> Any:
        if value is None or isinstance(value, (bool, str)):
            return value
        if isinstance(value, int) and not isinstance(value, Enum):
            return value
        if isinstance(value, float):
            return {"f": repr(value)} if value != value or value in (float("inf"), float("-inf")) else value
        if isinstance(value, np.generic):
            return {"s": value.dtype.str, "v": value.item() if value == value else repr(value.item())}
        ref = self._seen.get(id(value))
        if ref is not None:
            return {"r": ref}
        n = len(self._seen)
        self._seen[id(value)] = n
        self._keep.append(value)
        return {"n": n, **self._body(value)}

    def _body(self, value: Any) -> dict[str, Any]:
        if isinstance(value, np.ndarray):
            if value.dtype.hasobject:
                raise StateError("a mapper state array holds Python objects: only numeric arrays are kept")
            # copied (the mapper goes on changing its arrays), unless read-only and its own (a scan's)
            frozen = not value.flags.writeable and value.flags.owndata and value.flags.c_contiguous
            self.arrays.append(value if frozen else np.array(value, order="C", copy=True))
            return {"a": len(self.arrays) - 1, "ro": not value.flags.writeable}
        if isinstance(value, list):
            return {"l": [self.node(v) for v in value]}
        if isinstance(value, tuple):
            return {"t": [self.node(v) for v in value]}
        if isinstance(value, deque):
            return {"q": [self.node(v) for v in value], "max": value.maxlen}
        if isinstance(value, dict):
            return {"d": [[self.node(k), self.node(v)] for k, v in value.items()]}
        if isinstance(value, Enum):
            return {"e": _name(type(value)), "v": value.value}
        if isinstance(value, Kernel):
            return {"k": [str(value.stage), value.name, value.version, value.get_params()]}
        cls = type(value)
        name = _name(cls)
        if _CLASSES.get(name) is not cls:
            raise StateError(f"a mapper state holds a {name}: not a registered state class")
        skip = self._skip.get(cls, frozenset())
        fields = {k: self.node(v) for k, v in _attributes(value).items() if k not in skip}
        return {"o": name, "x": fields}


def _name(cls: type) -> str:
    return f"{cls.__module__}.{cls.__qualname__}"


def _attributes(obj: Any) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for klass in type(obj).__mro__:
        for slot in klass.__dict__.get("__slots__", ()):
            if slot not in ("__dict__", "__weakref__") and hasattr(obj, slot):
                out[slot] = getattr(obj, slot)
    out.update(getattr(obj, "__dict__", {}))
    return out


def encode_tree(
    root: Any, skip: dict[type, frozenset[str]] | None = None
) -> tuple[Any, tuple[np.ndarray, ...]]:
    """``root``'s tree and arrays; ``skip`` names attributes left out per class (kernels in force, caches
    and timings that the restoring side has of its own). :class:`StateError` on an unregistered class."""
    enc = _Encoder(skip or {})
    tree = enc.node(root)
    return tree, tuple(enc.arrays)


# ---------------------------------------------------------------------------------------------- decoding
class _Decoder:
    def __init__(self, arrays: tuple[np.ndarray, ...]) -> None:
        self.arrays = arrays
        self._made: dict[int, Any] = {}

    def node(self, tree: Any) -> Any:
        if tree is None or isinstance(tree, (bool, int, float, str)):
            return tree
        if not isinstance(tree, dict):
            raise StateError(f"a mapper state node is a {type(tree).__name__}: expected a value or an object")
        if "f" in tree:
            return float(tree["f"])
        if "s" in tree:
            v = tree["v"]
            return np.dtype(tree["s"]).type(float(v) if isinstance(v, str) else v)
        if "r" in tree:
            if tree["r"] not in self._made:
                raise StateError(f"a mapper state refers to object {tree['r']} before it is defined")
            return self._made[tree["r"]]
        n = tree.get("n")
        if not isinstance(n, int):
            raise StateError("a mapper state object has no number")
        return self._build(n, tree)

    def _build(self, n: int, tree: dict[str, Any]) -> Any:
        made = self._made
        if "a" in tree:
            idx = tree["a"]
            if not isinstance(idx, int) or not 0 <= idx < len(self.arrays):
                raise StateError(f"a mapper state refers to array {idx}: it holds {len(self.arrays)}")
            arr = np.array(self.arrays[idx], copy=True)
            if tree.get("ro"):
                arr.setflags(write=False)
            made[n] = arr
            return arr
        if "l" in tree:
            out: list[Any] = []
            made[n] = out
            out.extend(self.node(v) for v in tree["l"])
            return out
        if "q" in tree:
            dq: deque[Any] = deque(maxlen=tree.get("max"))
            made[n] = dq
            dq.extend(self.node(v) for v in tree["q"])
            return dq
        if "d" in tree:
            d: dict[Any, Any] = {}
            made[n] = d
            for k, v in tree["d"]:
                d[self.node(k)] = self.node(v)
            return d
        if "t" in tree:  # a tuple cannot refer to itself, so it is made from its items
            t = tuple(self.node(v) for v in tree["t"])
            made[n] = t
            return t
        if "e" in tree:
            cls = self._class(tree["e"])
            if not issubclass(cls, Enum):
                raise StateError(f"a mapper state names {tree['e']} as an enum: it is not one")
            made[n] = cls(tree["v"])
            return made[n]
        if "k" in tree:
            stage, name, version, params = tree["k"]
            made[n] = REGISTRY.create(Stage(stage), name, params, version)
            return made[n]
        if "o" in tree:
            cls = self._class(tree["o"])
            obj: Any = object.__new__(cls)
            made[n] = obj
            for key, value in tree["x"].items():
                object.__setattr__(obj, key, self.node(value))
            return obj
        raise StateError(f"a mapper state node has none of the known forms (keys {sorted(tree)})")

    @staticmethod
    def _class(name: Any) -> type:
        cls = _CLASSES.get(name) if isinstance(name, str) else None
        if cls is None:
            raise StateError(f"a mapper state names class {name!r}: not a registered state class")
        return cls


def decode_tree(state: MapperState) -> Any:
    """The objects ``state`` describes (new ones: nothing is shared with a live mapper).
    :class:`StateError` on anything it does not describe properly."""
    try:
        return _Decoder(state.arrays).node(state.tree)
    except StateError:
        raise
    except (LookupError, TypeError, ValueError, AttributeError) as exc:
        raise StateError(
            f"the mapping state does not describe a mapper ({type(exc).__name__}: {exc})"
        ) from None
