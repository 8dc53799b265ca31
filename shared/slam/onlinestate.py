"""An :class:`~shared.slam.OnlineGraphMapper`'s learned state as data, and a mapper restored from it
(docs/design.md §7, docs/loopclosure.md): the front end's state, the keyframes, the pose graph's nodes,
edges and estimate, the accepted closures, the scans kept for redraws, the shown map (the rebuilt one,
once a loop was closed) and the map drawn before loop closure was switched on.

What the worker had not finished is not lost: keyframes whose loop search was pending are searched again
after a restore with their saved inputs, and the latest rebuild under way is started again. The gtsam
solver is not saved: a restored graph replays the updates since its solver was last built from scratch
(:meth:`shared.slam.graph.PoseGraph.reattach`), so it goes on bit for bit as an uninterrupted one. Retired
keyframes and kept scans (:mod:`shared.slam.places`) are saved without their returns once no pending job
reads them. The records that grow with the distance driven (a keyframe, a loop closure, a kept scan) are
saved as the mapper's rows of them (``_fronts``, ``_odometry``, ``_pairs``, ``_closure_rows``,
``_scan_rows``) plus the returns still held, and made into objects again on restore: a state is taken in
array copies and a pass over the records, not an object tree per record (a day's 70,000 keyframes took
about 2 s to encode as objects, in the step). O(graph + held kept scans + map) both ways.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from shared.errors import StateError
from shared.pipeline import pipeline
from shared.pipeline.pipestate import PIPELINE_SKIP, adopt_pipeline
from shared.pipeline.state import MapperState, decode_tree, encode_tree, register_state_class
from shared.slam import closure, graph, mapper, places, rows, settings
from shared.types import Pose2D

if TYPE_CHECKING:
    from shared.slam.online import OnlineGraphMapper

__all__ = ["GRAPH_KIND", "graph_state", "restore_graph"]

GRAPH_KIND = "graph"

register_state_class(
    mapper.GraphMapper,
    mapper.Keyframe,
    mapper.LoopClosure,
    graph.PoseGraph,
    graph.Edge,
    closure.LoopMatch,
    settings.LoopClosureSettings,
    rows.Rows,
    places.Places,
)

_SKIP: dict[type, frozenset[str]] = {
    **PIPELINE_SKIP,
    # ``_now`` (what the front end made of the last scan) is read back off the restored front end
    # the records as objects are saved as rows (module docstring: _records, _restore_records)
    # ``_chain_sums`` is a cache of sums over ``_fronts`` and ``_seq_cov``, rebuilt on demand
    mapper.GraphMapper: frozenset({"_make", "_now", "keyframes", "closures", "_scans", "_chain_sums"}),
    graph.PoseGraph: frozenset({"_params", "_isam", "_new_factors", "_new_values", "_rider_poses"}),
}


def graph_state(online: OnlineGraphMapper, parts: dict[str, Any]) -> MapperState:
    """The state of ``online`` from ``parts`` (read under its lock: ``mapper``, ``shown``, ``base``,
    ``version``, ``closed``, ``rebuilt_at``, ``rebuilds``, ``searches`` (keyframe, due version, estimate,
    keyframes retired then, closures accepted then, matches or None) and ``redraw`` (version, estimate,
    kept scans, kept scans retired then, what the shown map took since) or None)."""
    tree, arrays = encode_tree({**parts, **_records(parts["mapper"])}, _SKIP)
    return MapperState(GRAPH_KIND, tree, arrays)


def _records(gm: mapper.GraphMapper) -> dict[str, Any]:
    """What the rows of ``gm``'s records leave out: the returns of the keyframes that still hold them
    ``(index, points, scan)`` and the kept scans still held ``(index, scan)``. O(records), one pass."""
    none = mapper._NO_POINTS
    returns = [
        (i, kf.points, kf.scan)
        for i, kf in enumerate(gm.keyframes)
        if kf.points is not none or kf.scan is not none
    ]
    scans = [(i, scan) for i, (_step, scan, _odometry) in enumerate(gm._scans) if scan is not None]
    return {"returns": returns, "scans": scans}


def _pose(row: list[float]) -> Pose2D | None:
    return None if math.isnan(row[0]) else Pose2D(row[0], row[1], row[2])


def _restore_records(gm: mapper.GraphMapper, returns: Any, scans: Any) -> None:
    """``gm``'s keyframes, closures and kept scans made again from its rows and ``returns``, ``scans``
    (:func:`_records`). :class:`StateError` when they do not fit together. O(records)."""
    fronts, odometry = gm._fronts.view().tolist(), gm._odometry.view().tolist()
    pairs, closed = gm._pairs.view().tolist(), gm._closure_rows.view().tolist()
    stepped = gm._scan_rows.view().tolist()
    if len(fronts) != len(odometry) or len(pairs) != len(closed) or len(stepped) != len(gm._kept):
        raise StateError("the graph mapper's state holds rows of its records that do not fit together")
    held = {int(i): (points, scan) for i, points, scan in returns}
    none = (mapper._NO_POINTS, mapper._NO_POINTS)
    gm.keyframes = [
        mapper.Keyframe(int(f[5]), Pose2D(f[0], f[1], f[2]), _pose(o), *held.get(i, none), f[3], f[4])
        for i, (f, o) in enumerate(zip(fronts, odometry, strict=True))
    ]
    gm.closures = [
        mapper.LoopClosure(int(k), int(c), Pose2D(x, y, th), share)
        for (k, c), (x, y, th, share) in zip(pairs, closed, strict=True)
    ]
    kept = dict(scans)
    gm._scans = [(int(r[0]), kept.get(i), _pose(r[1:])) for i, r in enumerate(stepped)]


def restore_graph(online: OnlineGraphMapper, state: MapperState) -> dict[str, Any]:
    """The parts of ``state`` made live for ``online`` (not stepped yet): the graph mapper with ``online``'s
    fresh front end holding the saved one's state and a new solver, the shown map likewise.
    :class:`StateError` if ``state`` is not a graph mapper's."""
    if state.kind != GRAPH_KIND:
        raise StateError(f"the mapping state is a {state.kind!r} state: expected a {GRAPH_KIND!r} state")
    parts = decode_tree(state)
    expected = {"mapper", "shown", "base", "version", "closed", "rebuilt_at", "rebuilds"}
    expected |= {"searches", "redraw", "returns", "scans"}
    if not isinstance(parts, dict) or set(parts) != expected:
        raise StateError(
            f"the graph mapper's state holds {sorted(parts) if isinstance(parts, dict) else parts!r}"
        )
    _check_jobs(parts["searches"], parts["redraw"])
    gm = parts["mapper"]
    if not isinstance(gm, mapper.GraphMapper) or not isinstance(gm.graph, graph.PoseGraph):
        raise StateError("the graph mapper's state holds no graph mapper")
    try:
        _restore_records(gm, parts.pop("returns"), parts.pop("scans"))
    except (TypeError, ValueError, LookupError) as exc:  # rows or returns of another shape
        raise StateError(f"the graph mapper's records do not parse ({type(exc).__name__}: {exc})") from None
    live = online._mapper
    gm._make = live._make
    gm.front = adopt_pipeline(live.front, gm.front)
    gm.adopt_front()
    gm.search_inline = live.search_inline
    gm.graph.reattach()
    shown = parts["shown"]
    if shown is not None:
        if not isinstance(shown, pipeline.Pipeline):
            raise StateError("the graph mapper's shown map is not a pipeline")
        parts["shown"] = adopt_pipeline(online._make(online.config), shown)
    return parts


def _estimate(value: Any) -> bool:
    return isinstance(value, np.ndarray) and value.ndim == 2 and value.shape[1] == 3


def _check_jobs(searches: Any, redraw: Any) -> None:
    """:class:`StateError` unless the pending jobs have the shapes :func:`graph_state` gives them."""
    for job in searches if isinstance(searches, list) else [None]:
        if not (
            isinstance(job, tuple)
            and len(job) == 6
            and isinstance(job[0], int)
            and isinstance(job[1], int)
            and _estimate(job[2])
            and isinstance(job[3], int)
            and isinstance(job[4], int)
            and (job[5] is None or isinstance(job[5], list))
        ):
            raise StateError(f"the graph mapper's pending loop search {job!r:.80} is not one")
    if redraw is not None and not (
        isinstance(redraw, tuple)
        and len(redraw) == 5
        and isinstance(redraw[0], int)
        and _estimate(redraw[1])
        and isinstance(redraw[2], int)
        and isinstance(redraw[3], int)
        and isinstance(redraw[4], list)
    ):
        raise StateError(f"the graph mapper's pending rebuild {redraw!r:.80} is not one")
