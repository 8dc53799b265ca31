"""Baselines the paper compares its mapping with: a line-segment EKF-SLAM (§6.3, Fig. 24).

:class:`EkfLineSlam` runs one scan at a time like :class:`shared.pipeline.Pipeline` (``step(scan)``,
``walls()``, ``trajectory``, ``step_ms``); its front end is split-and-merge line extraction
(:func:`split_and_merge`). Pure numpy, no I/O.
"""

from shared.baselines.ekf_lines import EkfLineSlam
from shared.baselines.ekf_params import EkfLineSlamParams
from shared.baselines.errors import BaselineError, BaselineParameterError
from shared.baselines.line_model import line_difference, lines_to_world, normalise_lines, predict_lines
from shared.baselines.split_merge import (
    LineObservations,
    SplitMergeParams,
    extract_lines,
    fit_line,
    split_and_merge,
)

__all__ = [
    "BaselineError",
    "BaselineParameterError",
    "EkfLineSlam",
    "EkfLineSlamParams",
    "LineObservations",
    "SplitMergeParams",
    "extract_lines",
    "fit_line",
    "line_difference",
    "lines_to_world",
    "normalise_lines",
    "predict_lines",
    "split_and_merge",
]
