"""Loop closure: a keyframe pose graph (gtsam) under the front end, the map rebuilt from its poses.

:class:`GraphMapper` is the entry point; :class:`LoopClosureSettings` what an operator tunes.
"""

from shared.slam.closure import LoopMatch, candidates, verify
from shared.slam.errors import LoopClosureSettingsError, OptimisationError, SlamError
from shared.slam.graph import Edge, PoseGraph
from shared.slam.information import MatchInformation, match_information
from shared.slam.mapper import GraphMapper, Keyframe, LoopClosure
from shared.slam.online import OnlineGraphMapper
from shared.slam.settings import LoopClosureSettings

__all__ = [
    "Edge",
    "GraphMapper",
    "Keyframe",
    "LoopClosure",
    "LoopClosureSettings",
    "LoopClosureSettingsError",
    "LoopMatch",
    "MatchInformation",
    "OnlineGraphMapper",
    "OptimisationError",
    "PoseGraph",
    "SlamError",
    "candidates",
    "match_information",
    "verify",
]
