"""A :class:`~shared.pipeline.Pipeline`'s learned state as data, and a pipeline restored from it
(docs/design.md §7): the wall map with its evidence, the free space and the cells seen free, the pose
tracker (pose, keyframe scan, local wall maps, learned odometry noise), the pending offline batches, the
centroids and the trajectory. The kernels in force are not in it: they follow the configuration the
restoring pipeline was built with. A pipeline stepped N scans, saved and restored, then stepped M more,
equals one stepped N + M scans (tests/shared/pipeline/test_pipestate.py). O(map + trajectory) both ways.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from shared.errors import StateError
from shared.pipeline import fusion_solve, localize, pipeline
from shared.pipeline.config import Mode
from shared.pipeline.freespace import FreeSpace, FreeSpaceModel
from shared.pipeline.gate import IcpGate
from shared.pipeline.odonoise import NoiseScale, OdometryNoise
from shared.pipeline.rangenoise import RangeNoise
from shared.pipeline.seenfree import SeenFree, SeenFreeModel
from shared.pipeline.stages import Chunk
from shared.pipeline.state import MapperState, decode_tree, encode_tree, register_state_class
from shared.pipeline.tracker import PoseTracker
from shared.pipeline.wallmap import MergeTolerances, WallMap
from shared.types import Pose2D
from shared.types.scan import BeamGeometry, Scan

if TYPE_CHECKING:
    from shared.pipeline.pipeline import Pipeline

__all__ = ["PIPELINE_KIND", "PIPELINE_SKIP", "adopt_pipeline", "pipeline_state", "restore_pipeline"]

PIPELINE_KIND = "pipeline"

register_state_class(
    pipeline.Pipeline,
    pipeline._Buffer,
    pipeline.MapState,
    Mode,
    FreeSpace,
    FreeSpaceModel,
    IcpGate,
    NoiseScale,
    OdometryNoise,
    RangeNoise,
    SeenFree,
    SeenFreeModel,
    Chunk,
    PoseTracker,
    MergeTolerances,
    WallMap,
    Pose2D,
    Scan,
    BeamGeometry,
    fusion_solve.Reference,
    localize.WallFit,
)

#: what a pipeline has of its own and is not saved: the configuration and the kernels built from it, a
#: cache of those kernels, and step timings
PIPELINE_SKIP: dict[type, frozenset[str]] = {
    pipeline.Pipeline: frozenset({"_config", "_kernels", "_by_k", "_step_ms", "_history"})
}


def pipeline_state(pipe: Pipeline) -> MapperState:
    """``pipe``'s learned state (a copy: stepping ``pipe`` on does not change it)."""
    tree, arrays = encode_tree(pipe, PIPELINE_SKIP)
    return MapperState(PIPELINE_KIND, tree, arrays)


def restore_pipeline(pipe: Pipeline, state: MapperState) -> None:
    """Put ``state`` into ``pipe``, a pipeline that has not stepped yet (built with the configuration
    to go on with). :class:`StateError` if ``state`` is not a pipeline's or ``pipe`` has stepped."""
    if state.kind != PIPELINE_KIND:
        raise StateError(f"the mapping state is a {state.kind!r} state: expected a {PIPELINE_KIND!r} state")
    adopt_pipeline(pipe, decode_tree(state))


def adopt_pipeline(pipe: Pipeline, saved: object) -> Pipeline:
    """``pipe`` (not stepped yet) with the learned state of ``saved``, a pipeline decoded from a state
    (which lacks the kernels: ``pipe`` has them, built from its configuration). Returns ``pipe``."""
    if pipe.version:
        raise StateError("a pipeline's state can be restored only before its first step")
    if type(saved) is not type(pipe):
        raise StateError(f"the mapping state holds a {type(saved).__name__}: expected a pipeline")
    for key, value in vars(saved).items():
        if key in PIPELINE_SKIP[pipeline.Pipeline]:
            continue
        if key not in vars(pipe):
            raise StateError(f"the mapping state has pipeline field {key!r}: this pipeline has none")
        setattr(pipe, key, value)
    return pipe
