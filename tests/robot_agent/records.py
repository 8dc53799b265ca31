"""Robot DB records for tests: a small, recognisable step per map version."""

from __future__ import annotations

from robot_agent.store_map import StepRecord

__all__ = ["step_record"]


def step_record(version: int) -> StepRecord:
    """Map version ``version``: one wall whose id is the version, the previous one removed, a pose and a
    centroid, stamped ``version * 0.1`` s."""
    return StepRecord(
        version=version,
        stamp_s=version * 0.1,
        source_index=version,
        segments=[[float(version), 0.0, 0.0, 1.0, float(version)]],
        removed=[version - 1] if version > 1 else [],
        pose=[version * 0.1, 1.0, 2.0, 0.5],
        centroids=[[0.5, 0.5]],
    )
