"""The pipeline's kernels (docs/design.md §4): the contract, the registry and every built-in kernel.

Importing this package registers the built-ins in :data:`REGISTRY`::

    from shared.kernels import REGISTRY
    dbscan = REGISTRY.create("noise-removal", "dbscan", {"epsilon_m": 0.05, "min_points": 5})
"""

from shared.kernels import clustering, lines, matching, noise, segmentation
from shared.kernels.base import (
    ClusteringKernel,
    Kernel,
    NoiseRemovalKernel,
    ScanMatchingKernel,
    SegmentationKernel,
    Stage,
    StraightLineKernel,
)
from shared.kernels.params import KernelParams, param
from shared.kernels.registry import REGISTRY, KernelInfo, KernelRegistry, register
from shared.kernels.results import Clusters, Lines, Match, NoiseResult, Segments

__all__ = [
    "REGISTRY",
    "ClusteringKernel",
    "Clusters",
    "Kernel",
    "KernelInfo",
    "KernelParams",
    "KernelRegistry",
    "Lines",
    "Match",
    "NoiseRemovalKernel",
    "NoiseResult",
    "ScanMatchingKernel",
    "SegmentationKernel",
    "Segments",
    "Stage",
    "StraightLineKernel",
    "clustering",
    "lines",
    "matching",
    "noise",
    "param",
    "register",
    "segmentation",
]
