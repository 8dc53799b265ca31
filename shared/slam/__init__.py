"""Loop closure: a keyframe pose graph (gtsam) under the front end, the map rebuilt from its poses.

:class:`GraphMapper` is the entry point; :class:`LoopClosureSettings` what an operator tunes.

The names are loaded when first used: the settings (which the control message and the pipeline's
configuration validate against, on the server too) must not pull in gtsam and the correlative matcher.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
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

#: public name -> the module that defines it
_WHERE = {
    "Edge": "graph",
    "GraphMapper": "mapper",
    "Keyframe": "mapper",
    "LoopClosure": "mapper",
    "LoopClosureSettings": "settings",
    "LoopClosureSettingsError": "errors",
    "LoopMatch": "closure",
    "MatchInformation": "information",
    "OnlineGraphMapper": "online",
    "OptimisationError": "errors",
    "PoseGraph": "graph",
    "SlamError": "errors",
    "candidates": "closure",
    "match_information": "information",
    "verify": "closure",
}


def __getattr__(name: str) -> Any:
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module 'shared.slam' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"shared.slam.{module}"), name)
    globals()[name] = value
    return value
